"""Simple shapes and rigid-body inertials of the robot, shared by the URDF and the MuJoCo MJCF.

The robot description (``robot.yaml``) holds the kinematics and the link masses; the shapes below
are project nominal values [N] for pictures and collisions (the paper gives none), named once here
so the URDF (:mod:`hexapod_model.urdf`) and the MJCF (:mod:`hexapod_sim.physics.mjcf`) draw the same robot.
Pure Python/numpy.
"""
from __future__ import annotations

from hexapod_model.description import Robot

FOOT_RADIUS_M = 0.008          # rubber foot-tip sphere
LINK_RADIUS_M = 0.007          # link capsules (visual; the tibia capsule also collides)
TRUNK_MARGIN_M = 0.02          # trunk plate reaches this far beyond the leg mounts
TRUNK_HALF_HEIGHT_M = 0.02
SERVO_HALF_SIZE_M = (0.025, 0.016, 0.019)   # AX-12A case 50 x 32 x 38 mm (visual only)
INERTIA_AXIAL_FRACTION = 0.1   # link inertia about its own axis, relative to the transverse one
ROBOT_RGBA = (0.15, 0.15, 0.17, 1.0)   # trunk and servo cases
LINK_RGBA = (0.85, 0.85, 0.88, 1.0)
FOOT_RGBA = (0.9, 0.3, 0.1, 1.0)


def trunk_geometry(robot: Robot) -> tuple[tuple[float, float, float], tuple[float, float, float]]:
    """Half sizes of the main trunk plate and of the cross plate reaching the middle mounts."""
    px = max(abs(m.px_m) for m in robot.legs)
    corner_py = max((abs(m.py_m) for m in robot.legs if abs(m.px_m) > 1e-9), default=0.05)
    mid_py = max(abs(m.py_m) for m in robot.legs)
    main = (px + TRUNK_MARGIN_M, corner_py + TRUNK_MARGIN_M, TRUNK_HALF_HEIGHT_M)
    cross = (0.05, mid_py + TRUNK_MARGIN_M / 2, TRUNK_HALF_HEIGHT_M * 0.9)
    return main, cross


def trunk_inertia(robot: Robot) -> tuple[float, float, float]:
    """Principal inertia of the trunk [kg m^2]: its mass as a solid box of the main plate."""
    main, _ = trunk_geometry(robot)
    mb = robot.body_mass_kg
    hx, hy, hz = (2 * v for v in main)
    return mb * (hy ** 2 + hz ** 2) / 12, mb * (hx ** 2 + hz ** 2) / 12, mb * (hx ** 2 + hy ** 2) / 12


def link_inertial(robot: Robot, leg: int, role: str) -> tuple[float, float, float]:
    """(mass, COM distance along the link, inertia about the COM) including a tibia payload.

    A payload (``mass_error`` effect) is a point mass at the tibia tip, combined with the tibia
    link exactly as :class:`hexapod_model.swing_model.LegModel` does.
    """
    link = robot.links[role]
    m, lc, i = link.mass_kg, link.com_from_joint_m, link.inertia_about_com_kgm2
    if role == 'tibia':
        payload = robot.leg_payload_kg(leg)
        if payload > 0:
            a3 = robot.dh['tibia'].a_m
            m_tot = m + payload
            lc_new = (m * lc + payload * a3) / m_tot
            i = i + m * (lc - lc_new) ** 2 + payload * (a3 - lc_new) ** 2
            m, lc = m_tot, lc_new
    return m, lc, i


def link_principal_inertia(robot: Robot, leg: int, role: str) -> tuple[float, float, float]:
    """Inertia about the COM along the link frame's x (the link axis), y and z (the joint axis)."""
    _m, _lc, i = link_inertial(robot, leg, role)
    return INERTIA_AXIAL_FRACTION * i, i, i
