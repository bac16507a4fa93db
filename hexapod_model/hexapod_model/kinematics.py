"""Leg forward and inverse kinematics (paper Sec. 4, Eq. 1-7). Pure numpy.

Frames: the body frame has x forward, y left, z up (metres). Each leg's coxa frame is the body
frame rotated by ``beta`` about z and shifted to ``(px, py, 0)`` (Eq. 3). With the DH parameters
of Table 1 (``alpha_1 = pi/2``) the femur and tibia joints rotate about horizontal axes and a
positive femur/tibia angle lifts the distal link.

The paper's Eq. 4-7 print the inverse with a mirrored sign convention (z down, x/y swapped in
the arctangent); this module implements the exact inverse of its own Eq. 1-3, which the tests
check as ``FK(IK(p)) == p``. The knee is always bent downwards (``psi_3 < 0``).
"""
from __future__ import annotations

import math

import numpy as np

from hexapod_model.description import JOINT_ROLES, LEGS, Robot


class UnreachableTargetError(ValueError):
    """A foot-tip target cannot be reached by the leg; the message says why."""


def dh_matrix(alpha: float, a: float, d: float, psi: float) -> np.ndarray:
    """Eq. 1: homogeneous DH transform of one link."""
    ca, sa, cp, sp = math.cos(alpha), math.sin(alpha), math.cos(psi), math.sin(psi)
    return np.array([[cp, -sp * ca, sp * sa, a * cp],
                     [sp, cp * ca, -cp * sa, a * sp],
                     [0.0, sa, ca, d],
                     [0.0, 0.0, 0.0, 1.0]])


def mount_matrix(robot: Robot, leg: int) -> np.ndarray:
    """Eq. 3: body frame <- coxa frame of ``leg``."""
    m = robot.leg(leg)
    c, s = math.cos(m.beta_rad), math.sin(m.beta_rad)
    return np.array([[c, -s, 0.0, m.px_m], [s, c, 0.0, m.py_m], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]])


def leg_frames(robot: Robot, leg: int, theta) -> list[np.ndarray]:
    """Body-frame poses of the coxa mount and of frames 1..3 (Eq. 2), for joint angles ``theta``."""
    theta = np.asarray(theta, dtype=float)
    if theta.shape != (3,) or not np.all(np.isfinite(theta)):
        raise ValueError(f'leg {leg}: joint angles must be 3 finite numbers, got {theta!r}')
    frames = [mount_matrix(robot, leg)]
    for role, th in zip(JOINT_ROLES, theta):
        dh = robot.dh[role]
        frames.append(frames[-1] @ dh_matrix(dh.alpha_rad, dh.a_m, dh.d_m, th + dh.theta_off_rad))
    return frames


def forward(robot: Robot, leg: int, theta) -> np.ndarray:
    """Foot-tip position in the body frame [m] for joint angles ``theta`` = (coxa, femur, tibia)."""
    return leg_frames(robot, leg, theta)[-1][:3, 3].copy()


def inverse(robot: Robot, leg: int, foot_body_m, check_limits: bool = True) -> np.ndarray:
    """Joint angles (coxa, femur, tibia) [rad] that put the foot-tip of ``leg`` at ``foot_body_m``.

    Raises :class:`UnreachableTargetError` when the point is out of the leg's reach, on the coxa
    axis, or needs an angle outside the joint limits (``check_limits``).
    """
    p = np.asarray(foot_body_m, dtype=float)
    if p.shape != (3,) or not np.all(np.isfinite(p)):
        raise UnreachableTargetError(f'leg {leg}: foot target must be 3 finite numbers, got {foot_body_m!r}')
    m = robot.leg(leg)
    dx, dy = p[0] - m.px_m, p[1] - m.py_m
    # Eq. 4: coxa angle from the horizontal direction to the target, relative to the mount angle.
    c, s = math.cos(m.beta_rad), math.sin(m.beta_rad)
    x_c, y_c = c * dx + s * dy, -s * dx + c * dy        # target in the coxa frame
    a1, a2, a3 = robot.dh['coxa'].a_m, robot.dh['femur'].a_m, robot.dh['tibia'].a_m
    if math.hypot(x_c, y_c) < 1e-9:
        raise UnreachableTargetError(f'leg {leg}: target {p.tolist()} lies on the coxa axis')
    th1 = math.atan2(y_c, x_c) - robot.dh['coxa'].theta_off_rad
    # Eq. 5: the target in the femur's vertical plane (radial distance beyond the coxa, height).
    r = math.hypot(x_c, y_c) - a1
    z = p[2] - robot.dh['coxa'].d_m
    dist = math.hypot(r, z)
    if dist > a2 + a3 - 1e-9 or dist < abs(a2 - a3) + 1e-9:
        raise UnreachableTargetError(
            f'leg {leg}: target {np.round(p, 4).tolist()} is {dist * 1000:.1f} mm from the femur joint; '
            f'reach is {abs(a2 - a3) * 1000:.0f}..{(a2 + a3) * 1000:.0f} mm')
    # Eq. 6-7: cosine law; knee bent downwards.
    beta = math.acos(np.clip((a2 ** 2 - a3 ** 2 + dist ** 2) / (2 * a2 * dist), -1.0, 1.0))
    gamma = math.acos(np.clip((a2 ** 2 + a3 ** 2 - dist ** 2) / (2 * a2 * a3), -1.0, 1.0))
    psi2 = math.atan2(z, r) + beta
    psi3 = -(math.pi - gamma)
    theta = np.array([th1, psi2 - robot.dh['femur'].theta_off_rad, psi3 - robot.dh['tibia'].theta_off_rad])
    theta[0] = (theta[0] + math.pi) % (2 * math.pi) - math.pi
    if check_limits:
        for role, th in zip(JOINT_ROLES, theta):
            lo, hi = robot.joint_limits_rad[role]
            if not lo <= th <= hi:
                raise UnreachableTargetError(
                    f'leg {leg}: target {np.round(p, 4).tolist()} needs {role} angle {th:.3f} rad, '
                    f'outside the limits [{lo}, {hi}]')
    return theta


def stance_feet(robot: Robot, theta=None) -> np.ndarray:
    """Foot-tips of all six legs (rows = legs 1..6) in the body frame for one joint configuration."""
    theta = robot.default_stance_rad if theta is None else theta
    return np.array([forward(robot, leg, theta) for leg in LEGS])


def planar_leg_angles(robot: Robot, theta) -> tuple[float, float]:
    """Absolute angles above the horizontal of the femur and tibia links, for a level body."""
    psi2 = theta[1] + robot.dh['femur'].theta_off_rad
    psi3 = theta[2] + robot.dh['tibia'].theta_off_rad
    return psi2, psi2 + psi3
