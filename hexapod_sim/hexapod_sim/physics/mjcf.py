"""MJCF of the hexapod generated from the one robot description. Pure Python/numpy, no MuJoCo import.

Body and joint frames follow the DH chain of :mod:`hexapod_model.kinematics` exactly, so a MuJoCo
joint angle *is* the DH joint variable ``theta`` (``psi = theta + theta_off``):

* trunk: the body frame (x forward, y left, z up); a free joint unless ``fixed_base``.
* ``leg{l}_coxa`` body: at the leg mount ``(px, py, 0)``, rotated by ``beta + theta_off_1`` about z
  (Eq. 3); its hinge ``leg{l}_coxa`` turns about the body z axis.
* each following link body sits at the end of the previous link, ``(a, 0, d)`` rotated by ``alpha``
  about x and by its own ``theta_off`` about z (Eq. 1); its hinge turns about its z axis.
* the foot-tip (site ``leg{l}_foot_tip``) is at ``(a3, 0, d3)`` of the tibia frame; the contact geom
  ``leg{l}_foot`` is a sphere of radius :data:`FOOT_RADIUS_M` centred there.

Each hinge is an AX-12A: one default class per joint role carries ``armature = J R^2``,
``damping = B R^2`` and ``frictionloss = tau_c R`` (paper Table 3 reflected to the joint, exactly
the terms of the swing-down model, Eq. 14). The servo firmware itself is not in the MJCF: the
simulator computes its torque at 1 kHz and writes it to the ``motor`` actuator of the joint.

Effects from the description (``robot.joint_effects``) that change the mechanics are built in:
extra Coulomb friction and viscous damping (per-joint attributes), payload (a point mass at the
tibia tip, folded into the tibia inertial exactly as the swing-down model does), and backlash:
the motor hinge then drives a ``leg{l}_{role}_rotor`` body of negligible mass and the link hangs on
a second hinge ``leg{l}_{role}_backlash`` with range ``+-width/2`` (a hard-ish joint limit plays
the gear teeth). MuJoCo solves a joint limit as a constraint, robustly; the servo's
potentiometer sits on the output shaft, so the position the firmware sees is motor + play.
Effects that act in the firmware or on the bus (static friction, torque saturation, dead-band,
readout delay) are applied by :mod:`hexapod_sim.physics.plant`.

The shapes, colours and inertials shared with the URDF are in :mod:`hexapod_model.shapes`; the
sim-only contact values (not in the robot description, so named once here) are project nominal
values [N].
"""
from __future__ import annotations

import math
import os
from dataclasses import dataclass

import numpy as np

from hexapod_model.description import JOINT_ROLES, LEGS, Robot, joint_name
from hexapod_model.dictionary import T_DS, joint_terms
from hexapod_model.joints import JOINTS, Joint
from hexapod_model.kinematics import forward
from hexapod_model.servo import tick_to_theta
from hexapod_model.shapes import (  # noqa: F401
    FOOT_RADIUS_M,
    FOOT_RGBA,
    LINK_RADIUS_M,
    LINK_RGBA,
    ROBOT_RGBA,
    SERVO_HALF_SIZE_M,
    link_inertial,
    link_principal_inertia,
    trunk_geometry,
    trunk_inertia,
)
from hexapod_model.swing_model import joint_damping_nms_per_rad
from hexapod_sim.physics.terrain import Terrain, make_terrain
from hexapod_sim.physics.terrain_geoms import _mat_to_quat

# ----------------------------------------------------------------------------- sim nominal values [N]
TIMESTEP_S = 0.001             # physics step = the firmware period (1 ms or finer keeps the firmware grid)
FOOT_FRICTION = 1.0            # rubber on wood
SPAWN_CLEARANCE_M = 0.0005     # the robot is spawned this far above the terrain under its feet
FIXED_BASE_HEIGHT_M = 0.40     # trunk height when welded in the air (fixed_base=True)
# Dry friction as a (nearly) hard constraint. MuJoCo's default impedance (0.9) lets a joint loaded
# below its friction level creep (a femur held by a 0.3 N m break-away torque slid 60 ticks in 2 s);
# at 0.999 it creeps 0.02 tick/s (0.9999: 0.002 tick/s but ~10 % slower: more Newton iterations),
# close to the exact Coulomb/stiction law of the swing-down model.
FRICTION_SOLIMP = '0.999 0.999 0.001 0.5 2'
# Foot friction made hard relative to the normal force: with MuJoCo's default (pyramidal cones,
# impratio 1) a standing robot's feet crept outward ~0.9 mm/s and the body sank; elliptic cones with
# impratio 100 reduce that to ~0.03 mm/s at no extra cost.
CONTACT_IMPRATIO = 100
BACKLASH_SOLIMP = '0.99 0.999 0.001 0.5 2'
# Semi-implicit Euler: MuJoCo integrates joint damping implicitly with it, and joint damping is the
# only velocity-dependent force of this model (motors have none), so every step is bit for bit the
# implicit-fast one (a test checks it) while skipping implicit-fast's derivative pass (~4 % of a step).
INTEGRATOR = 'Euler'
# Sparse constraint Jacobian: a joint-friction row touches one DOF and a foot contact one leg plus the
# trunk, so the Newton solver's Hessian is cheaper sparse than dense (MuJoCo picks dense below 60
# DOFs); the same solution to round-off (1e-14 rad after 3 s of the blocks walk), ~5 % of a step.
# MuJoCo 4.0.0's sparse Cholesky can give Newton a wrong Hessian factor on some trees (fixed in 4.0.1,
# not on the package registry yet); test_mjcf checks that this tree still gets the dense solution.
JACOBIAN = 'sparse'
ROTOR_MASS_KG = 1e-6           # backlash rotor body: negligible (the rotor inertia is the armature)
ROTOR_INERTIA_KGM2 = 1e-10


@dataclass(frozen=True)
class Scene:
    """A generated scene: the MJCF string plus what the simulator needs to know about it."""

    xml: str
    terrain: Terrain | None          # None when fixed_base (no ground)
    fixed_base: bool
    spawn_height_m: float            # trunk height of the ``home`` keyframe
    backlash_joints: tuple[str, ...]  # joints that got a backlash hinge
    timestep_s: float


def _fmt(v) -> str:
    return ' '.join(f'{float(x):.9g}' for x in np.ravel(v))


def _rz(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _rx(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def servo_range_rad(robot: Robot) -> tuple[float, float]:
    """Physical travel of an AX-12A in joint angle: ticks 0..max_tick around the centre tick."""
    s = robot.servo
    return (float(tick_to_theta(0, s)), float(tick_to_theta(s.max_tick, s)))


def home_foot_height_m(robot: Robot) -> float:
    """Lowest foot-tip z in the body frame at the default stance (negative: below the trunk)."""
    return float(min(forward(robot, leg, robot.default_stance_rad)[2] for leg in LEGS))


def _joint_attrs(robot: Robot, joint: Joint) -> str:
    """Per-joint overrides of the role class for friction/damping effects ('' when nominal)."""
    e = robot.joint_effects(joint)
    s = robot.servo
    attrs = []
    if e.extra_coulomb_nm:
        attrs.append(f'frictionloss="{s.reflected_coulomb_nm + e.extra_coulomb_nm:.9g}"')
    motor = joint_terms(robot, joint)[T_DS]          # a weak motor's back-EMF damping (hexapod_model.dictionary)
    if e.extra_damping_nms_per_rad or e.damping_ratio != 1.0 or motor != 1.0:
        attrs.append(f'damping="{joint_damping_nms_per_rad(s, e, motor):.9g}"')
    return (' ' + ' '.join(attrs)) if attrs else ''


def _link_geoms(robot: Robot, leg: int, role: str, indent: str) -> list[str]:
    dh = robot.dh[role]
    end = (dh.a_m, 0.0, dh.d_m)
    out = [f'{indent}<geom class="visual" type="capsule" fromto="0 0 0 {_fmt(end)}" size="{LINK_RADIUS_M}" '
           f'rgba="{_fmt(LINK_RGBA)}"/>']
    if role in ('coxa', 'femur'):
        # the next joint's servo case sits at the end of this link
        out.append(f'{indent}<geom class="visual" type="box" pos="{_fmt(end)}" size="{_fmt(SERVO_HALF_SIZE_M)}" '
                   f'rgba="{_fmt(ROBOT_RGBA)}"/>')
    if role == 'tibia':
        a = dh.a_m
        out.append(f'{indent}<geom name="leg{leg}_tibia_col" class="collision" type="capsule" '
                   f'fromto="{0.15 * a:.9g} 0 0 {0.75 * a:.9g} 0 {0.75 * dh.d_m:.9g}" size="{LINK_RADIUS_M}"/>')
        out.append(f'{indent}<geom name="leg{leg}_foot" class="foot" type="sphere" pos="{_fmt(end)}" '
                   f'size="{FOOT_RADIUS_M}"/>')
        out.append(f'{indent}<site name="leg{leg}_foot_tip" pos="{_fmt(end)}" size="0.003"/>')
    return out


def _leg_xml(robot: Robot, leg: int, backlash: set[str]) -> list[str]:
    mount = robot.leg(leg)
    lines = []
    depth = 2
    closers = []
    parent_end = None          # (a, d, alpha) of the previous link
    for role in JOINT_ROLES:
        dh = robot.dh[role]
        joint = Joint(leg, role)
        name = str(joint)
        ind = '  ' * depth
        if parent_end is None:
            pos = (mount.px_m, mount.py_m, 0.0)
            R = _rz(mount.beta_rad) @ _rz(dh.theta_off_rad)
        else:
            a, d, alpha = parent_end
            pos = (a, 0.0, d)
            R = _rx(alpha) @ _rz(dh.theta_off_rad)
        q = _mat_to_quat(R)
        m, lc, _ = link_inertial(robot, leg, role)
        inertial = (f'<inertial pos="{lc:.9g} 0 0" mass="{m:.9g}" '
                    f'diaginertia="{_fmt(link_principal_inertia(robot, leg, role))}"/>')
        if name in backlash:
            # motor hinge -> massless rotor body -> backlash hinge -> link body
            lines.append(f'{ind}<body name="{name}_rotor" pos="{_fmt(pos)}" quat="{_fmt(q)}">')
            lines.append(f'{ind}  <inertial pos="0 0 0" mass="{ROTOR_MASS_KG}" '
                         f'diaginertia="{ROTOR_INERTIA_KGM2} {ROTOR_INERTIA_KGM2} {ROTOR_INERTIA_KGM2}"/>')
            lines.append(f'{ind}  <joint name="{name}" class="{role}"{_joint_attrs(robot, joint)}/>')
            w = robot.joint_effects(joint).backlash_width_rad
            depth += 1
            ind = '  ' * depth
            lines.append(f'{ind}<body name="leg{leg}_{role}">')
            lines.append(f'{ind}  <joint name="{name}_backlash" class="backlash" range="{-w / 2:.9g} {w / 2:.9g}"/>')
            closers.append('  ' * (depth - 1) + '</body>')
        else:
            lines.append(f'{ind}<body name="leg{leg}_{role}" pos="{_fmt(pos)}" quat="{_fmt(q)}">')
            lines.append(f'{ind}  <joint name="{name}" class="{role}"{_joint_attrs(robot, joint)}/>')
        lines.append(f'{ind}  {inertial}')
        lines.extend(_link_geoms(robot, leg, role, ind + '  '))
        closers.append(ind + '</body>')
        parent_end = (dh.a_m, dh.d_m, dh.alpha_rad)
        depth += 1
    lines.extend(reversed(closers))
    return lines


def robot_body_xml(robot: Robot, fixed_base: bool, base_pos_m, backlash: set[str]) -> str:
    """The ``<body name="trunk">`` element with all six legs, trunk origin at ``base_pos_m``."""
    main, cross = trunk_geometry(robot)
    mb = robot.body_mass_kg
    ixx, iyy, izz = trunk_inertia(robot)
    lines = [f'<body name="trunk" pos="{_fmt(base_pos_m)}">']
    if not fixed_base:
        lines.append('  <freejoint name="root"/>')
    lines += [
        f'  <inertial pos="0 0 0" mass="{mb:.9g}" diaginertia="{ixx:.9g} {iyy:.9g} {izz:.9g}"/>',
        f'  <geom name="trunk_col" class="collision" type="box" size="{_fmt(main)}"/>',
        f'  <geom class="visual" type="box" size="{_fmt(main)}" rgba="{_fmt(ROBOT_RGBA)}"/>',
        f'  <geom class="visual" type="box" size="{_fmt(cross)}" rgba="{_fmt(ROBOT_RGBA)}"/>',
        '  <site name="imu" pos="0 0 0" size="0.01"/>',
    ]
    for leg in LEGS:
        mount = robot.leg(leg)
        # coxa servo case at the mount (visual)
        lines.append(f'  <geom class="visual" type="box" pos="{mount.px_m:.9g} {mount.py_m:.9g} 0" '
                     f'size="{_fmt(SERVO_HALF_SIZE_M)}" quat="{_fmt(_mat_to_quat(_rz(mount.beta_rad)))}" '
                     f'rgba="{_fmt(ROBOT_RGBA)}"/>')
        lines.extend(_leg_xml(robot, leg, backlash))
    lines.append('</body>')
    return '\n'.join('    ' + x for x in lines)


def _defaults_xml(robot: Robot, timestep_s: float) -> str:
    s = robot.servo
    lo, hi = servo_range_rad(robot)
    # joint friction nearly as hard as MuJoCo allows (time constant 4 physics steps): with the default
    # 0.02 s a stuck joint creeps below ~0.08 rad/s instead of sticking, unlike the servo model
    role_classes = '\n'.join(
        f'      <default class="{role}"><joint type="hinge" axis="0 0 1" armature="{s.reflected_inertia_kgm2:.9g}" '
        f'damping="{s.reflected_damping_nms_per_rad:.9g}" frictionloss="{s.reflected_coulomb_nm:.9g}" '
        f'solimpfriction="{FRICTION_SOLIMP}" solreffriction="{4 * timestep_s:.9g} 1" '
        f'limited="true" range="{lo:.9g} {hi:.9g}"/></default>'
        for role in JOINT_ROLES)
    # backlash hinge: no own dynamics; the limit (gear teeth) is as stiff as MuJoCo allows: time constant
    # 2 physics steps, impedance 0.99-0.999 (the default 4-step/0.9 limit let a loaded gear
    # penetrate 35 mrad; this one holds its width within 2 % at rest, ~7 mrad in violent impacts)
    return f'''  <default>
{role_classes}
      <default class="backlash"><joint type="hinge" axis="0 0 1" limited="true" armature="0" damping="0"
        frictionloss="0" solreflimit="{2 * timestep_s:.9g} 1" solimplimit="{BACKLASH_SOLIMP}"/></default>
      <default class="visual"><geom contype="0" conaffinity="0" group="2" mass="0" density="0"/></default>
      <default class="collision"><geom contype="1" conaffinity="2" group="3" mass="0" density="0"
        rgba="0.5 0.5 0.9 0.4"/></default>
      <default class="foot"><geom contype="1" conaffinity="2" group="2" mass="0" density="0" condim="3"
        friction="{FOOT_FRICTION} 0.005 0.0001" rgba="{_fmt(FOOT_RGBA)}"/></default>
      <default class="terrain"><geom contype="2" conaffinity="1" group="0" condim="3"
        friction="{FOOT_FRICTION} 0.005 0.0001"/></default>
  </default>'''


def scene(robot: Robot, terrain: str | Terrain = 'flat', seed: int = 0, fixed_base: bool = False,
          timestep_s: float = TIMESTEP_S, start_xy_m: tuple[float, float] = (0.0, 0.0)) -> Scene:
    """The complete MJCF scene: robot, terrain (none when ``fixed_base``), actuators, sensors, keyframe.

    The ``home`` keyframe puts the trunk above ``start_xy_m`` (level, facing +x) and every leg in
    ``robot.default_stance_rad``, with the feet :data:`SPAWN_CLEARANCE_M` above the highest terrain
    point under them.
    """
    if not (0 < timestep_s <= robot.servo.control_period_s):
        raise ValueError(f'timestep_s must be in (0, {robot.servo.control_period_s}] (the firmware period), '
                         f'got {timestep_s!r}')
    ratio = robot.servo.control_period_s / timestep_s
    if abs(ratio - round(ratio)) > 1e-9:
        raise ValueError(f'timestep_s={timestep_s} must divide the firmware period '
                         f'{robot.servo.control_period_s} s exactly')
    backlash = {str(j) for j in JOINTS if robot.joint_effects(j).backlash_width_rad > 0}
    if fixed_base:
        ter = None
        base_h = FIXED_BASE_HEIGHT_M
    else:
        ter = terrain if isinstance(terrain, Terrain) else make_terrain(terrain, seed)
        sx, sy = (float(v) for v in start_xy_m)
        if not (math.isfinite(sx) and math.isfinite(sy)):
            raise ValueError(f'start_xy_m must be two finite numbers, got {start_xy_m!r}')
        feet = np.array([forward(robot, leg, robot.default_stance_rad) for leg in LEGS])
        ground = float(np.max(ter.height_at(feet[:, 0] + sx, feet[:, 1] + sy)))
        base_h = ground - home_foot_height_m(robot) + FOOT_RADIUS_M + SPAWN_CLEARANCE_M
    order = [joint_name(leg, r) for leg in LEGS for r in JOINT_ROLES]
    key_q = []
    if not fixed_base:
        key_q += [sx, sy, base_h, 1.0, 0.0, 0.0, 0.0]
    stance = dict(zip(JOINT_ROLES, robot.default_stance_rad))
    for name in order:                    # MuJoCo qpos order = depth-first body order (leg by leg)
        key_q.append(stance[name.split('_', 1)[1]])
        if name in backlash:
            key_q.append(0.0)
    s = robot.servo
    actuators = '\n'.join(
        f'    <motor name="{n}" joint="{n}" gear="1" ctrllimited="true" '
        f'ctrlrange="{-s.stall_torque_nm:.9g} {s.stall_torque_nm:.9g}"/>' for n in order)
    assets = ter.mjcf_assets() if ter is not None else ''
    ground_geoms = ter.mjcf_geoms() if ter is not None else ''
    xml = f'''<mujoco model="{robot.name}">
  <compiler angle="radian" autolimits="true"/>
  <option timestep="{timestep_s:.9g}" integrator="{INTEGRATOR}" jacobian="{JACOBIAN}" cone="elliptic"
          impratio="{CONTACT_IMPRATIO}" gravity="0 0 {-robot.gravity_mps2:.9g}"/>
  <size memory="8M"/>
  <visual>
    <headlight ambient="0.35 0.35 0.35" diffuse="0.6 0.6 0.6" specular="0.1 0.1 0.1"/>
    <global offwidth="1280" offheight="960" azimuth="150" elevation="-25"/>
    <quality shadowsize="2048"/>
  </visual>
{_defaults_xml(robot, timestep_s)}
  <asset>
    {assets}
  </asset>
  <worldbody>
    <light name="sun" pos="0.5 -1 2.5" dir="-0.2 0.4 -1" directional="true" castshadow="true"/>
    {ground_geoms}
{robot_body_xml(robot, fixed_base, (0.0, 0.0, base_h) if fixed_base else (sx, sy, base_h), backlash)}
  </worldbody>
  <actuator>
{actuators}
  </actuator>
  <keyframe>
    <key name="home" qpos="{_fmt(key_q)}"/>
  </keyframe>
</mujoco>
'''
    return Scene(xml=xml, terrain=ter, fixed_base=fixed_base, spawn_height_m=base_h,
                 backlash_joints=tuple(n for n in order if n in backlash), timestep_s=timestep_s)


def mjcf_file_text(robot: Robot, terrain: str = 'flat', seed: int = 0,
                   start_xy_m: tuple[float, float] = (0.0, 0.0), overlays=()) -> str:
    """The scene of :func:`scene` as the text of one stand-alone MJCF file, with a header that says
    where it came from (the text is the same string the simulator compiles, so nothing can differ)."""
    sc = scene(robot, terrain, seed=seed, start_xy_m=start_xy_m)
    how = f'--terrain {terrain} --seed {seed}'
    if tuple(start_xy_m) != (0.0, 0.0):
        how += f' --start-x {start_xy_m[0]:g} --start-y {start_xy_m[1]:g}'
    for o in overlays or ():
        how += f' --overlay {o}'
    header = (f'<!-- Generated from the robot description ({robot.name}) by hexapod_sim.physics.mjcf; do not edit.\n'
              f'     Regenerate: ./hexapod sim --mjcf OUT.xml {how}\n'
              f'     View: python -m mujoco.viewer --mjcf OUT.xml -->\n')
    return header + sc.xml


def write_mjcf(robot: Robot, path, **kwargs) -> str:
    """Write :func:`mjcf_file_text` to ``path`` (replaced atomically); returns the path written."""
    text = mjcf_file_text(robot, **kwargs)
    tmp = f'{path}.tmp{os.getpid()}'
    try:
        with open(tmp, 'w', encoding='utf-8') as f:
            f.write(text)
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.remove(tmp)
    return str(path)
