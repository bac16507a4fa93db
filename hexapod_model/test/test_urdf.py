"""The URDF generated from the one description, checked by an independent library (Pinocchio):
forward kinematics against the DH kinematics (Eq. 1-3), rigid-body dynamics against the swing-down
model's Euler-Lagrange terms (Eq. 11), and refusal of descriptions that cannot become a URDF."""
import itertools
import math
import xml.etree.ElementTree as ET
from dataclasses import replace

import numpy as np
import pytest

from hexapod_model.description import ALL_JOINTS, JOINT_ROLES, LEGS, DescriptionError, LinkInertial, load_robot
from hexapod_model.kinematics import leg_frames
from hexapod_model.shapes import INERTIA_AXIAL_FRACTION
from hexapod_model.swing_model import LegModel, coxa_axis_inertia_kgm2
from hexapod_model.urdf import (
    ROOT_LINK,
    check_robot,
    foot_link,
    frame_poses,
    link_transforms,
    no_load_speed_rad_s,
    urdf_joints,
    urdf_xml,
    write_urdf,
)

pin = pytest.importorskip('pinocchio', reason='pin (Pinocchio) is pinned in requirements/py.txt')


@pytest.fixture(scope='module')
def robot():
    return load_robot()


@pytest.fixture(scope='module')
def model(robot):
    m = pin.buildModelFromXML(urdf_xml(robot))        # fixed base: the trunk held level
    m.gravity.linear = np.array([0.0, 0.0, -robot.gravity_mps2])
    m.armature[:] = robot.servo.reflected_inertia_kgm2   # J R^2: URDF has no rotor inertia; Eq. 14
    return m


def _v_index(model, leg, role):
    return model.idx_vs[model.getJointId(f'leg{leg}_{role}')]


def test_structure(robot, model):
    root = ET.fromstring(urdf_xml(robot))
    assert root.tag == 'robot' and root.get('name') == robot.name
    links = {e.get('name') for e in root.findall('link')}
    assert {ROOT_LINK, 'trunk'} | {f'leg{leg}_{r}' for leg in LEGS for r in JOINT_ROLES} \
        | {foot_link(leg) for leg in LEGS} == links
    revolute = {e.get('name'): e for e in root.findall('joint') if e.get('type') == 'revolute'}
    assert set(revolute) == set(ALL_JOINTS)
    for name, e in revolute.items():
        lim = e.find('limit')
        lo, hi = robot.joint_limits(name)
        assert (float(lim.get('lower')), float(lim.get('upper'))) == (lo, hi)
        assert float(lim.get('effort')) == robot.servo.stall_torque_nm
        assert e.find('axis').get('xyz') == '0 0 1'
    # AX-12A no-load speed (datasheet 114 rpm at 12 V) from the description's motor constants
    assert no_load_speed_rad_s(robot) * 60 / (2 * math.pi) == pytest.approx(114, rel=0.03)
    # every link carries a visual and a collision shape; masses add up to the description's total
    for e in root.findall('link'):
        if e.get('name') != ROOT_LINK:
            assert e.find('visual') is not None and e.find('collision') is not None, e.get('name')
    assert sum(i.mass for i in model.inertias) == pytest.approx(robot.total_mass_kg, rel=1e-12)
    assert model.nq == 18 and [model.names[j] for j in range(1, model.njoints)] == list(ALL_JOINTS)


def test_forward_kinematics_equals_dh_for_every_leg_over_a_grid(robot, model):
    data = model.createData()
    grids = {r: np.linspace(*robot.joint_limits_rad[r], 6) for r in JOINT_ROLES}
    worst = 0.0
    for leg in LEGS:
        fid = model.getFrameId(foot_link(leg), pin.FrameType.BODY)
        iq = [model.idx_qs[model.getJointId(f'leg{leg}_{r}')] for r in JOINT_ROLES]
        for theta in itertools.product(*grids.values()):
            q = pin.neutral(model)
            q[iq] = theta
            pin.framesForwardKinematics(model, data, q)
            dh = leg_frames(robot, leg, theta)[-1]         # Eq. 1-3: the foot-tip frame
            worst = max(worst, float(np.abs(data.oMf[fid].homogeneous - dh).max()))
    assert worst < 1e-12, worst


def test_link_transforms_are_the_urdf_joints(robot, model):
    """The transforms recorded as TF (link_transforms / frame_poses) are Pinocchio's frames."""
    data = model.createData()
    rng = np.random.default_rng(1)
    q = pin.neutral(model)
    for leg, role in itertools.product(LEGS, JOINT_ROLES):
        q[model.idx_qs[model.getJointId(f'leg{leg}_{role}')]] = rng.uniform(*robot.joint_limits_rad[role])
    positions = {name: float(q[model.idx_qs[model.getJointId(name)]]) for name in ALL_JOINTS}
    pin.framesForwardKinematics(model, data, q)
    poses = frame_poses(robot, positions)
    for name, pose in poses.items():
        assert np.abs(data.oMf[model.getFrameId(name, pin.FrameType.BODY)].homogeneous - pose).max() < 1e-12, name
    chained = {ROOT_LINK: np.eye(4)}
    pairs = link_transforms(robot, positions, movable=False) + link_transforms(robot, positions)
    for parent, child, t in sorted(pairs, key=lambda p: [j.child for j in urdf_joints(robot)].index(p[1])):
        chained[child] = chained[parent] @ t
    assert set(chained) == set(poses)
    for name in poses:
        assert np.allclose(chained[name], poses[name], atol=1e-14)


def _leg_config(robot, model, rng, leg):
    iv = [_v_index(model, leg, r) for r in JOINT_ROLES]
    q = pin.neutral(model)
    for k, r in enumerate(JOINT_ROLES):
        q[iv[k]] = rng.uniform(*robot.joint_limits_rad[r])
    v = np.zeros(model.nv)
    v[iv[1:]] = rng.uniform(-6.0, 6.0, 2)          # femur and tibia swinging, coxa held (Eq. 11)
    return q, v, iv


def test_dynamics_equal_the_swing_down_models_euler_lagrange_terms(robot, model):
    """Eq. 11 with Eq. 14: (D(q) + J R^2) q'' + C(q, q') q' + G(q) = tau, for the femur and tibia of
    every leg, against Pinocchio's CRBA (mass matrix), RNEA (Coriolis and gravity) and ABA. The
    swing-down model's terms are taken from its integration kernel: one control period with no
    servo torque, friction or damping gives q'' = (q'_1 - q'_0) / dt exactly (semi-implicit Euler)."""
    data = model.createData()
    rng = np.random.default_rng(0)
    zero = np.zeros(model.nv)
    for leg in LEGS:
        lm = LegModel(robot, leg, control=False, friction=False, damping=False)
        for _ in range(40):
            q, v, iv = _leg_config(robot, model, rng, leg)
            ft = iv[1:]
            M = pin.crba(model, data, q)
            M = np.triu(M) + np.triu(M, 1).T
            G = pin.computeGeneralizedGravity(model, data, q)
            Cv = pin.rnea(model, data, q, v, zero) - G
            qdd = pin.aba(model, data, q, v, zero)
            D = lm.mass_matrix(q[ft])
            np.testing.assert_allclose(D, M[np.ix_(ft, ft)], rtol=1e-12, atol=0)
            np.testing.assert_allclose(lm.gravity_torque_nm(q[ft]), G[ft], rtol=1e-10, atol=1e-15)
            ro = lm.rollout(q[ft], v[ft], np.zeros((1, 2)))
            qdd_model = (ro.qd_rad_s[1] - ro.qd_rad_s[0]) / lm.dt_s
            np.testing.assert_allclose(qdd_model, qdd[ft], rtol=1e-9, atol=1e-9)
            cv_model = -D @ qdd_model - lm.gravity_torque_nm(q[ft])     # the kernel's C(q, q') q'
            np.testing.assert_allclose(cv_model, Cv[ft], rtol=1e-6, atol=1e-12)


def test_coxa_inertia_differs_only_by_the_links_axial_inertia(robot, model):
    """The coxa model takes femur and tibia as slender rods; the URDF (like the MJCF) gives each link
    an inertia about its own axis of INERTIA_AXIAL_FRACTION of the transverse one. Nothing else
    differs (Pinocchio's M[coxa, coxa] minus J R^2)."""
    data = model.createData()
    rng = np.random.default_rng(2)
    for leg in LEGS:
        for _ in range(10):
            q, _v, iv = _leg_config(robot, model, rng, leg)
            M = pin.crba(model, data, q)
            femur, tibia = q[iv[1]], q[iv[2]]
            psi2 = femur + robot.dh['femur'].theta_off_rad
            psi23 = psi2 + tibia + robot.dh['tibia'].theta_off_rad
            axial = INERTIA_AXIAL_FRACTION * (robot.links['femur'].inertia_about_com_kgm2 * math.sin(psi2) ** 2
                                              + robot.links['tibia'].inertia_about_com_kgm2 * math.sin(psi23) ** 2)
            pin_coxa = M[iv[0], iv[0]] - robot.servo.reflected_inertia_kgm2
            assert pin_coxa - coxa_axis_inertia_kgm2(robot, leg, femur, tibia) == pytest.approx(axial, rel=1e-9)
            # up to 3.1 % of the links' own inertia about the axis (leg curled in), but the kernel
            # integrates it with the rotor's J R^2: there it is below 0.2 %
            assert axial < 0.002 * M[iv[0], iv[0]]


@pytest.mark.parametrize('mutate, key', [
    (lambda r: replace(r, links={**r.links, 'femur': replace(r.links['femur'], mass_kg=-0.08)}),
     'links.femur.mass_kg'),
    (lambda r: replace(r, dh={**r.dh, 'tibia': replace(r.dh['tibia'], a_m=float('nan'))}), 'dh.tibia.a_m'),
    (lambda r: replace(r, links={**r.links, 'coxa': LinkInertial(0.08, 0.026, 0.0)}),
     'links.coxa.inertia_about_com_kgm2'),
    (lambda r: replace(r, total_mass_kg=1.0), 'total_mass_kg'),
])
def test_refuses_a_robot_that_cannot_be_a_urdf(robot, tmp_path, mutate, key):
    bad = mutate(robot)
    with pytest.raises(DescriptionError, match=key.replace('.', r'\.')):
        check_robot(bad)
    out = tmp_path / 'robot.urdf'
    with pytest.raises(DescriptionError):
        write_urdf(bad, out)
    assert list(tmp_path.iterdir()) == []


def test_write_urdf_atomic_and_readable(robot, tmp_path):
    out = write_urdf(robot, tmp_path / 'hexapod.urdf')
    assert out.read_text() == urdf_xml(robot)
    assert [p.name for p in tmp_path.iterdir()] == ['hexapod.urdf']
    assert oct(out.stat().st_mode & 0o777) != oct(0o600)
    assert pin.buildModelFromUrdf(str(out)).nq == 18
