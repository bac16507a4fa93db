"""URDF of the hexapod generated from the one robot description. Pure Python/numpy, no ROS import.

Frames follow the DH chain of :mod:`hexapod_model.kinematics` exactly, so a URDF joint position
*is* the DH joint variable ``theta`` (``psi = theta + theta_off``) and the frame ``leg{l}_foot`` is
the DH end frame of Eq. 2 (its origin the foot tip):

* ``base_link`` (root, no inertia: KDL refuses an inertial root) -> fixed ``trunk`` (the body frame
  of the paper: x forward, y left, z up; the trunk's mass and shapes). ``world -> base_link`` is
  the body pose (the sim's truth in bags and the live view).
* ``leg{l}_coxa`` joint at the leg mount ``(px, py, 0)``, rotated by ``beta + theta_off_1`` about z
  (Eq. 3); each following joint at the end of the previous link, ``(a, 0, d)`` rotated by
  ``alpha`` about x and by its own ``theta_off`` about z (Eq. 1). Every revolute joint turns about
  its frame's z axis, within ``joint_limits_rad``; effort limit = stall torque, velocity limit =
  the no-load speed ``U / (K R)`` of the servo at the supply voltage.
* ``leg{l}_foot``: fixed at ``(a3, 0, d3)`` of the tibia, rotated by ``alpha_3`` about x.

Inertials are the nominal model's (:mod:`hexapod_model.shapes`: link masses and COMs of the
description, the same tensors as the MJCF). Shapes: boxes for the trunk and servo cases,
cylinders for the links, a sphere for the foot (URDF has no capsule).

:func:`check_robot` refuses a robot that cannot become a valid URDF (non-finite or negative
values) naming the description key; :func:`write_urdf` writes atomically (nothing is left
behind on error). The joint list (:func:`urdf_joints`) also gives the transforms of every frame
for TF (:func:`link_transforms`), so TF and URDF cannot disagree.
"""
from __future__ import annotations

import math
import os
import tempfile
import warnings
from dataclasses import dataclass
from pathlib import Path
from xml.sax.saxutils import quoteattr

import numpy as np
from scipy.spatial.transform import Rotation

from hexapod_model.description import JOINT_ROLES, LEGS, DescriptionError, Robot, joint_name
from hexapod_model.shapes import (
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

ROOT_LINK = 'base_link'
TRUNK_LINK = 'trunk'
WORLD_FRAME = 'world'


def foot_link(leg: int) -> str:
    return f'leg{leg}_foot'


@dataclass(frozen=True)
class UrdfJoint:
    """One URDF joint: ``parent -> child`` is ``origin @ Rz(position)`` (revolute) or ``origin``."""

    name: str
    kind: str                    # 'revolute' | 'fixed'
    parent: str
    child: str
    origin: np.ndarray           # 4x4, parent <- joint frame at position 0
    lower: float = 0.0
    upper: float = 0.0

    def transform(self, position: float = 0.0) -> np.ndarray:
        if self.kind == 'fixed':
            return self.origin
        c, s = math.cos(position), math.sin(position)
        rz = np.array([[c, -s, 0.0, 0.0], [s, c, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]])
        return self.origin @ rz


def _pose(xyz, rot: np.ndarray) -> np.ndarray:
    t = np.eye(4)
    t[:3, :3] = rot
    t[:3, 3] = xyz
    return t


def _rz(a: float) -> np.ndarray:
    return Rotation.from_euler('z', a).as_matrix()


def _rx(a: float) -> np.ndarray:
    return Rotation.from_euler('x', a).as_matrix()


# ----------------------------------------------------------------------------- validation
def check_robot(robot: Robot) -> None:
    """Raise :class:`DescriptionError` naming the key when ``robot`` cannot become a valid URDF.

    :func:`hexapod_model.description.load_robot` refuses such values already; this also guards a
    :class:`Robot` built in code (e.g. with ``dataclasses.replace``).
    """
    def finite(v, key):
        if not isinstance(v, (int, float)) or not math.isfinite(v):
            raise DescriptionError(f'{key}: must be a finite number for the URDF, got {v!r}')
        return float(v)

    finite(robot.total_mass_kg, 'total_mass_kg')
    for role in JOINT_ROLES:
        dh = robot.dh[role]
        for f in ('alpha_rad', 'a_m', 'd_m', 'theta_off_rad'):
            finite(getattr(dh, f), f'dh.{role}.{f}')
        link = robot.links[role]
        for f in ('mass_kg', 'com_from_joint_m', 'inertia_about_com_kgm2'):
            v = finite(getattr(link, f), f'links.{role}.{f}')
            if f != 'com_from_joint_m' and v <= 0:
                raise DescriptionError(f'links.{role}.{f}: must be > 0 for the URDF, got {v!r}')
        lo, hi = (finite(v, f'joint_limits_rad.{role}') for v in robot.joint_limits_rad[role])
        if lo >= hi:
            raise DescriptionError(f'joint_limits_rad.{role}: low {lo} must be below high {hi}')
    for m in robot.legs:
        for f in ('beta_rad', 'px_m', 'py_m'):
            finite(getattr(m, f), f'legs[leg={m.leg}].{f}')
    s = robot.servo
    for f in ('stall_torque_nm', 'supply_voltage_v', 'torque_constant_nm_per_a', 'gear_ratio'):
        if finite(getattr(s, f), f'servo.{f}') <= 0:
            raise DescriptionError(f'servo.{f}: must be > 0 for the URDF, got {getattr(s, f)!r}')
    if not robot.body_mass_kg > 0:
        raise DescriptionError(f'total_mass_kg={robot.total_mass_kg} leaves no mass for the trunk '
                               f'(six legs weigh {6 * robot.leg_mass_kg:.3f} kg)')


def no_load_speed_rad_s(robot: Robot) -> float:
    """Output speed of an unloaded servo at the supply voltage: ``U / (K R)`` (back-EMF = K)."""
    s = robot.servo
    return s.supply_voltage_v / (s.torque_constant_nm_per_a * s.gear_ratio)


# ----------------------------------------------------------------------------- joints and transforms
def urdf_joints(robot: Robot) -> list[UrdfJoint]:
    """Every joint of the URDF in tree order (base_link -> trunk, then leg by leg)."""
    out = [UrdfJoint('trunk_fixed', 'fixed', ROOT_LINK, TRUNK_LINK, np.eye(4))]
    for leg in LEGS:
        mount = robot.leg(leg)
        parent = TRUNK_LINK
        prev = None                       # previous DH row: the joint sits at the end of its link
        for role in JOINT_ROLES:
            dh = robot.dh[role]
            if prev is None:
                origin = _pose((mount.px_m, mount.py_m, 0.0), _rz(mount.beta_rad + dh.theta_off_rad))
            else:
                origin = _pose((prev.a_m, 0.0, prev.d_m), _rx(prev.alpha_rad) @ _rz(dh.theta_off_rad))
            name = joint_name(leg, role)
            lo, hi = robot.joint_limits_rad[role]
            out.append(UrdfJoint(name, 'revolute', parent, f'leg{leg}_{role}', origin, lo, hi))
            parent, prev = f'leg{leg}_{role}', dh
        out.append(UrdfJoint(f'leg{leg}_foot_fixed', 'fixed', parent, foot_link(leg),
                             _pose((prev.a_m, 0.0, prev.d_m), _rx(prev.alpha_rad))))
    return out


def link_transforms(robot: Robot, positions: dict[str, float], joints: list[UrdfJoint] | None = None,
                    movable: bool = True) -> list[tuple[str, str, np.ndarray]]:
    """(parent, child, 4x4) of the revolute joints (``movable``) or of the fixed ones, with the
    revolute joints at ``positions`` (joint name -> theta; a missing joint is left out)."""
    out = []
    for j in joints if joints is not None else urdf_joints(robot):
        if movable and j.kind == 'revolute' and j.name in positions:
            out.append((j.parent, j.child, j.transform(float(positions[j.name]))))
        elif not movable and j.kind == 'fixed':
            out.append((j.parent, j.child, j.origin))
    return out


def frame_poses(robot: Robot, positions: dict[str, float]) -> dict[str, np.ndarray]:
    """Pose of every link frame relative to ``base_link`` (joints missing from ``positions`` at 0)."""
    poses = {ROOT_LINK: np.eye(4)}
    for j in urdf_joints(robot):
        poses[j.child] = poses[j.parent] @ j.transform(float(positions.get(j.name, 0.0)))
    return poses


# ----------------------------------------------------------------------------- XML
def _f(v: float) -> str:
    v = float(v)
    return '0' if v == 0 else repr(v)


def _origin(t: np.ndarray) -> str:
    with warnings.catch_warnings():        # a cylinder turned onto x is a gimbal lock: still exact
        warnings.simplefilter('ignore', UserWarning)
        rpy = Rotation.from_matrix(t[:3, :3]).as_euler('xyz')     # extrinsic x-y-z = URDF's rpy
    rpy = [0.0 if abs(a) < 1e-15 else a for a in rpy]
    return f'<origin xyz="{" ".join(_f(v) for v in t[:3, 3])}" rpy="{" ".join(_f(v) for v in rpy)}"/>'


def _cylinder_along(end, radius: float, material: str, tag: str = 'visual') -> str:
    """A cylinder from the frame origin to ``end`` = (x, 0, z) (URDF cylinders run along their z)."""
    x, _, z = end
    length = math.hypot(x, z)
    pose = _pose((x / 2, 0.0, z / 2), Rotation.from_euler('y', math.atan2(x, z)).as_matrix())
    mat = f'<material name="{material}"/>' if tag == 'visual' else ''
    return (f'<{tag}>{_origin(pose)}<geometry><cylinder radius="{_f(radius)}" length="{_f(length)}"/></geometry>'
            f'{mat}</{tag}>')


def _box(center, rot: np.ndarray, half, material: str | None, tag: str = 'visual') -> str:
    mat = f'<material name="{material}"/>' if material and tag == 'visual' else ''
    return (f'<{tag}>{_origin(_pose(center, rot))}<geometry><box size="{" ".join(_f(2 * h) for h in half)}"/>'
            f'</geometry>{mat}</{tag}>')


def _inertial(mass: float, com, principal) -> str:
    ixx, iyy, izz = principal
    return (f'<inertial><origin xyz="{" ".join(_f(v) for v in com)}" rpy="0 0 0"/><mass value="{_f(mass)}"/>'
            f'<inertia ixx="{_f(ixx)}" ixy="0" ixz="0" iyy="{_f(iyy)}" iyz="0" izz="{_f(izz)}"/></inertial>')


def urdf_xml(robot: Robot) -> str:
    """The URDF text of ``robot`` (checked with :func:`check_robot` first)."""
    check_robot(robot)
    main, cross = trunk_geometry(robot)
    effort, velocity = robot.servo.stall_torque_nm, no_load_speed_rad_s(robot)
    lines = ['<?xml version="1.0"?>',
             f'<!-- Generated by hexapod_model.urdf from the robot description ({robot.name}); do not edit. -->',
             f'<robot name={quoteattr(robot.name)}>']
    for name, rgba in (('body', ROBOT_RGBA), ('link', LINK_RGBA), ('foot', FOOT_RGBA)):
        lines.append(f'  <material name="{name}"><color rgba="{" ".join(_f(v) for v in rgba)}"/></material>')
    lines.append(f'  <link name="{ROOT_LINK}"/>')
    trunk = [f'  <link name="{TRUNK_LINK}">', '    ' + _inertial(robot.body_mass_kg, (0, 0, 0), trunk_inertia(robot)),
             '    ' + _box((0, 0, 0), np.eye(3), main, 'body'), '    ' + _box((0, 0, 0), np.eye(3), cross, 'body'),
             '    ' + _box((0, 0, 0), np.eye(3), main, None, 'collision')]
    for leg in LEGS:          # coxa servo case at each mount
        m = robot.leg(leg)
        trunk.append('    ' + _box((m.px_m, m.py_m, 0.0), _rz(m.beta_rad), SERVO_HALF_SIZE_M, 'body'))
    lines += trunk + ['  </link>']
    for leg in LEGS:
        for role in JOINT_ROLES:
            dh = robot.dh[role]
            mass, lc, _ = link_inertial(robot, leg, role)
            end = (dh.a_m, 0.0, dh.d_m)
            body = [_inertial(mass, (lc, 0.0, 0.0), link_principal_inertia(robot, leg, role))]
            if math.hypot(dh.a_m, dh.d_m) > 1e-9:  # a zero-length link has no cylinder
                body += [_cylinder_along(end, LINK_RADIUS_M, 'link'),
                         _cylinder_along(end, LINK_RADIUS_M, 'link', 'collision')]
            if role in ('coxa', 'femur'):           # the next joint's servo case at the end of the link
                body.append(_box(end, np.eye(3), SERVO_HALF_SIZE_M, 'body'))
            lines += [f'  <link name="leg{leg}_{role}">'] + ['    ' + b for b in body] + ['  </link>']
        sphere = f'<geometry><sphere radius="{_f(FOOT_RADIUS_M)}"/></geometry>'
        lines += [f'  <link name="{foot_link(leg)}">',
                  f'    <visual><origin xyz="0 0 0" rpy="0 0 0"/>{sphere}<material name="foot"/></visual>',
                  f'    <collision><origin xyz="0 0 0" rpy="0 0 0"/>{sphere}</collision>', '  </link>']
    for j in urdf_joints(robot):
        parts = [f'  <joint name="{j.name}" type="{j.kind}">', f'    <parent link="{j.parent}"/>',
                 f'    <child link="{j.child}"/>', '    ' + _origin(j.origin)]
        if j.kind == 'revolute':
            parts += ['    <axis xyz="0 0 1"/>',
                      f'    <limit lower="{_f(j.lower)}" upper="{_f(j.upper)}" effort="{_f(effort)}" '
                      f'velocity="{_f(velocity)}"/>']
        lines += parts + ['  </joint>']
    lines.append('</robot>')
    return '\n'.join(lines) + '\n'


def write_urdf(robot: Robot, path: str | os.PathLike) -> Path:
    """Write the URDF to ``path`` atomically (a temporary file renamed into place); returns the path.

    Raises :class:`DescriptionError` (nothing written) when the robot cannot become a valid URDF,
    :class:`OSError` when the file cannot be written.
    """
    text = urdf_xml(robot)
    out = Path(path)
    fd, tmp = tempfile.mkstemp(prefix='.' + out.name + '.', dir=out.parent if str(out.parent) else '.')
    try:
        with os.fdopen(fd, 'w') as f:
            f.write(text)
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)          # what open() would have given, not mkstemp's 0600
        os.replace(tmp, out)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return out
