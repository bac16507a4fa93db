"""AX-12A position units and the servo firmware's control law. Pure numpy.

The firmware is modelled as the project's servo contract: every control
period (1 ms) it reads the integer present tick and the integer goal tick and outputs, at the
joint, ``clip((stall / slope) * (goal - present), -stall, stall)`` (paper Eq. 13 in output
units). A compliance margin (dead-band) removes the first ``margin`` ticks of error. Outside the
margin the AX-12A adds its *punch* (register 48, at least 32 of 1023: the e-manual's range starts
there, so every AX-12A has one): the drive starts at the punch where the error leaves the margin
and rises along the slope from there, ``sign(e) min(punch + gain (|e| - margin), max)``. The
swing-down model, the MuJoCo sim and the bus emulator all call :func:`firmware_torque_nm`.
"""
from __future__ import annotations

import math

import numpy as np

from hexapod_model.description import BusJoint, ServoParams


def theta_to_tick(theta_rad, servo: ServoParams):
    """Continuous joint-space tick of a DH joint angle (tick 512 = theta 0)."""
    return servo.center_tick + np.asarray(theta_rad, dtype=float) / servo.rad_per_tick


def tick_to_theta(tick, servo: ServoParams):
    """DH joint angle [rad] of a (possibly fractional) joint-space tick."""
    return (np.asarray(tick, dtype=float) - servo.center_tick) * servo.rad_per_tick


def quantize_tick(tick, servo: ServoParams):
    """What the servo reports: the nearest integer tick within 0..1023."""
    return np.clip(np.rint(tick), 0, servo.max_tick).astype(np.int64)


def firmware_torque_nm(goal_tick, present_tick, gain_nm_per_tick: float, torque_max_nm: float,
                       margin_ticks: float = 0.0, punch_nm: float = 0.0):
    """Joint torque the firmware outputs for integer goal and present ticks (vectorised).

    Zero within the compliance margin; outside it the punch plus the slope's gain times the error
    beyond the margin, limited to ``torque_max_nm``, with the error's sign.
    """
    err = np.asarray(goal_tick, dtype=float) - np.asarray(present_tick, dtype=float)
    mag = np.abs(err) - margin_ticks
    drive = np.where(mag > 0.0, np.minimum(punch_nm + gain_nm_per_tick * mag, torque_max_nm), 0.0)
    return np.where(err > 0.0, drive, -drive)


def firmware_torque_scalar(err_tick: float, gain_nm_per_tick: float, torque_max_nm: float,
                           margin_ticks: float, punch_nm: float = 0.0) -> float:
    """:func:`firmware_torque_nm` for one integer error ``goal - present``, in plain float arithmetic.

    The scalar twin for compiled kernels (the swing-down model wraps it with numba): the same
    operations in the same order, so it returns the same float for every error (a test checks it
    over the whole tick range).
    """
    mag = abs(err_tick) - margin_ticks
    if mag <= 0.0:
        return 0.0
    tau = punch_nm + gain_nm_per_tick * mag
    if tau > torque_max_nm:
        tau = torque_max_nm
    return tau if err_tick > 0.0 else -tau


def servo_tick(theta_rad: float, servo: ServoParams, bus: BusJoint) -> float:
    """Raw servo tick on the bus for a joint angle, with the joint's mounting direction/offset."""
    return servo.center_tick + bus.direction * theta_rad / servo.rad_per_tick + bus.offset_ticks


def servo_theta(tick: float, servo: ServoParams, bus: BusJoint) -> float:
    """Joint angle [rad] of a raw servo tick (inverse of :func:`servo_tick`)."""
    return bus.direction * (tick - servo.center_tick - bus.offset_ticks) * servo.rad_per_tick


def joint_tick_of_servo_tick(tick, servo: ServoParams, bus: BusJoint):
    """A raw servo tick on the joint's tick axis (:func:`theta_to_tick`'s): the mounting direction
    and offset undone, exactly (an integer raw tick stays an integer; vectorised)."""
    return servo.center_tick + bus.direction * (np.asarray(tick, dtype=float) - servo.center_tick - bus.offset_ticks)


def goal_joint_tick(theta_rad, servo: ServoParams, bus: BusJoint) -> np.ndarray:
    """The integer goal the servo receives for commanded joint angles, on the joint's tick axis.

    The driver writes ``rint`` of the raw servo tick (mounting direction and offset applied) and
    clips it to the servo's range; mapped back to the joint's tick axis (:func:`theta_to_tick`'s).
    """
    raw = quantize_tick(np.array([servo_tick(float(v), servo, bus) for v in np.atleast_1d(theta_rad)]), servo)
    return joint_tick_of_servo_tick(raw, servo, bus)


def winding_current_a(torque_nm, speed_rad_s, servo: ServoParams):
    """Winding current [A] (signed, as the torque) of a servo whose firmware asks for ``torque_nm`` while the
    joint turns at ``speed_rad_s``.

    The AX-12A's P controller sets the motor *voltage* (Eq. 13: V = k_P err); the torque the firmware
    model outputs is the torque that voltage gives at stall, ``K_t V / R_w`` with ``K_t = K R`` at
    the joint. Turning, the motor's back-EMF ``K_t omega`` opposes the voltage, so the winding carries
    ``I = (V - K_t omega) / R_w = tau / K_t - K_t omega / R_w``. The dynamics have that back-EMF
    torque ``K_t^2 omega / R_w`` (0.17 N m s/rad at the joint) inside the damping B R^2 of Table 3
    (0.20 N m s/rad): K^2 / R_w = 2.6e-6 of B = 3.12e-6 N m s. Where the firmware outputs no torque
    (torque off, or no error) the H-bridge does not drive the winding: no current.
    """
    kt = servo.torque_constant_nm_per_a * servo.gear_ratio
    tau = np.asarray(torque_nm, dtype=float)
    return np.where(tau != 0.0, tau / kt - kt * np.asarray(speed_rad_s, dtype=float) / servo.winding_resistance_ohm, 0.0)


def electrical_power_w(torque_nm, speed_rad_s, servo: ServoParams):
    """Electrical power a servo draws from the battery: ``V I`` (copper loss ``I^2 R_w`` plus the
    back-EMF's share ``K_t omega I``), with V and I of :func:`winding_current_a`. Never negative: the
    AX-12A's H-bridge does not return a braking motor's energy to the battery. At rest it is the
    copper loss of the holding current."""
    tau = np.asarray(torque_nm, dtype=float)
    i = winding_current_a(tau, speed_rad_s, servo)
    volts = tau / (servo.torque_constant_nm_per_a * servo.gear_ratio) * servo.winding_resistance_ohm
    return np.maximum(volts * i, 0.0)


def winding_loss_w(torque_nm, speed_rad_s, servo: ServoParams):
    """Heat dissipated in the winding (I^2 R_w), with the current of :func:`winding_current_a`."""
    i = winding_current_a(torque_nm, speed_rad_s, servo)
    return i * i * servo.winding_resistance_ohm


def degrees_per_tick(servo: ServoParams) -> float:
    return math.degrees(servo.rad_per_tick)


# Status-packet error bits of the AX-12A (Protocol 1.0), the one definition: the driver's protocol,
# the bus emulator and the sim import them; hexapod_msgs/msg/ServoStatus ERR_* carry the same
# values (a test compares them).
ERR_INPUT_VOLTAGE = 0x01
ERR_ANGLE_LIMIT = 0x02
ERR_OVERHEATING = 0x04
ERR_RANGE = 0x08
ERR_CHECKSUM = 0x10
ERR_OVERLOAD = 0x20
ERR_INSTRUCTION = 0x40
ERROR_BIT_NAMES = (
    (ERR_INPUT_VOLTAGE, 'input voltage out of range'),
    (ERR_ANGLE_LIMIT, 'goal outside the angle limits'),
    (ERR_OVERHEATING, 'overheating'),
    (ERR_RANGE, 'value out of range'),
    (ERR_CHECKSUM, 'instruction checksum error'),
    (ERR_OVERLOAD, 'overload'),
    (ERR_INSTRUCTION, 'instruction error'),
)


def describe_error(bits: int) -> str:
    """Human-readable list of the error bits set in a status-packet error byte ('' if none)."""
    return ', '.join(name for bit, name in ERROR_BIT_NAMES if bits & bit)
