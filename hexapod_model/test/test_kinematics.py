"""Forward/inverse kinematics (Eq. 1-7) against hand-computed values."""
import math

import numpy as np
import pytest

from hexapod_model.description import LEGS, load_robot
from hexapod_model.kinematics import UnreachableTargetError, forward, inverse, stance_feet


@pytest.fixture(scope='module')
def robot():
    return load_robot()


def test_default_stance_by_hand(robot):
    # home stance theta = (0, 0.5, -0.8): psi2 = 0.5 - 0.22 = 0.28, psi3 = -0.8 - 0.81 = -1.61
    # (Table 1 offsets). In the leg's vertical plane:
    r = 0.052 + 0.066 * math.cos(0.28) + 0.138 * math.cos(0.28 - 1.61)
    z = 0.066 * math.sin(0.28) + 0.138 * math.sin(0.28 - 1.61)
    assert r == pytest.approx(0.14834, abs=1e-5) and z == pytest.approx(-0.11578, abs=1e-5)
    feet = stance_feet(robot)
    # Table 2 mounts: (px, py, beta) -> foot = mount + r (cos beta, sin beta)
    mounts = [(0.1206, 0.0605, math.pi / 4), (0.1206, -0.0605, 7 * math.pi / 4), (-0.1206, 0.0605, 3 * math.pi / 4),
              (-0.1206, -0.0605, 5 * math.pi / 4), (0.0, 0.1005, math.pi / 2), (0.0, -0.1005, 3 * math.pi / 2)]
    for foot, (px, py, b) in zip(feet, mounts):
        assert foot == pytest.approx([px + r * math.cos(b), py + r * math.sin(b), z], abs=1e-9)
    # front-left foot by hand: 120.6 + 148.34 cos 45deg = 225.49 mm, 60.5 + 104.89 = 165.39 mm
    assert feet[0][:2] * 1000 == pytest.approx([225.49, 165.39], abs=0.01)


def test_femur_lifts_with_positive_angle(robot):
    assert forward(robot, 1, [0, 0.3, 0])[2] > forward(robot, 1, [0, 0, 0])[2]
    assert forward(robot, 1, [0, 0, 0.3])[2] > forward(robot, 1, [0, 0, 0])[2]


@pytest.mark.parametrize('leg', LEGS)
def test_fk_of_ik_is_identity_over_grid(robot, leg):
    base = stance_feet(robot)[leg - 1]
    m = robot.leg(leg)
    outward = np.array([math.cos(m.beta_rad), math.sin(m.beta_rad), 0.0])
    side = np.array([-outward[1], outward[0], 0.0])
    n = 0
    for dr in np.linspace(-0.03, 0.02, 5):
        for ds in np.linspace(-0.05, 0.05, 5):
            for dz in np.linspace(-0.04, 0.05, 5):
                p = base + dr * outward + ds * side + np.array([0, 0, dz])
                th = inverse(robot, leg, p)
                assert forward(robot, leg, th) == pytest.approx(p, abs=1e-9)
                n += 1
    assert n == 125


@pytest.mark.parametrize('target', [[1.0, 0.0, 0.0], [0.1206, 0.0605, -0.5], [0.13, 0.07, 0.0]])
def test_unreachable_raises(robot, target):
    with pytest.raises(UnreachableTargetError, match='leg 1'):
        inverse(robot, 1, target)


def test_nan_target_and_joint_limits(robot):
    with pytest.raises(UnreachableTargetError, match='finite'):
        inverse(robot, 2, [float('nan'), 0, 0])
    # straight sideways behind the leg: coxa angle of ~pi, outside the coxa limit
    m = robot.leg(1)
    p = np.array([m.px_m, m.py_m, 0]) - 0.18 * np.array([math.cos(m.beta_rad), math.sin(m.beta_rad), 0])
    p[2] = -0.13
    with pytest.raises(UnreachableTargetError, match='coxa angle'):
        inverse(robot, 1, p)


@pytest.mark.parametrize('leg', LEGS)
def test_ik_of_fk_recovers_joint_grid(robot, leg):
    m = robot.leg(leg)
    n = 0
    for th1 in np.linspace(-0.8, 0.8, 5):
        for th2 in np.linspace(-1.0, 1.2, 6):
            for th3 in np.linspace(-1.0, 0.75, 6):  # knee bent down: psi3 = th3 - 0.81 < 0
                th = np.array([th1, th2, th3])
                p = forward(robot, leg, th)
                ang = m.beta_rad + th1
                radial = (p[0] - m.px_m) * math.cos(ang) + (p[1] - m.py_m) * math.sin(ang)
                if radial < robot.dh['coxa'].a_m + 0.01:
                    continue    # foot folded back behind the femur joint: IK resolves the other branch
                assert inverse(robot, leg, p) == pytest.approx(th, abs=1e-9)
                n += 1
    assert n > 100
