"""Servo and bus health as standard ROS diagnostics (diagnostic_msgs/DiagnosticArray on /diagnostics).

The mapping is plain Python (:func:`servo_status`, :func:`bus_status` -> :class:`Status`), shared
by the driver and the sim node; :func:`diagnostic_array` turns statuses into the ROS message (the
only function here that imports ROS). ``rqt_robot_monitor`` and Foxglove's diagnostics panels
group the statuses by name: ``<node>: servo leg1_coxa (id 1)``, ``<node>: bus``.

Levels (servo):

* ERROR: the servo does not answer; an alarm that stops it (overheating, overload, input voltage);
  torque limit 0 (the AX-12A's alarm shutdown left it limp); temperature at or above the
  description's ``servo.shutdown_temperature_c``.
* WARN: temperature within :data:`TEMPERATURE_WARN_MARGIN_K` of the shutdown temperature; a
  command error bit (angle limit, range, checksum, instruction); torque off without an alarm
  (emergency stop, start-up).
* OK otherwise.

Bus: ERROR when every read of the window failed; WARN when some failed, when no read completed in
the window, or when the mean read time ``T_com`` exceeds :data:`T_COM_WARN_FACTOR` times the
description's ``bus.t_com_s`` (the swing-down model's Eq. 17 timing assumes it).

The ServoDiagnostics message of hexapod_msgs stays for the controller; this is for the tools.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from hexapod_model.contract import stamp_parts
from hexapod_model.description import Robot

OK, WARN, ERROR, STALE = 0, 1, 2, 3          # diagnostic_msgs/DiagnosticStatus levels
LEVEL_NAMES = {OK: 'OK', WARN: 'WARN', ERROR: 'ERROR', STALE: 'STALE'}
TEMPERATURE_WARN_MARGIN_K = 10.0             # [N] WARN this close to the shutdown temperature
T_COM_WARN_FACTOR = 2.0                      # [N] WARN when reads take this much longer than modelled

# Protocol 1.0 status-packet error byte: bit -> (name, stops the servo). hexapod_msgs/ServoStatus
# carries the same masks (a test checks them against it and the driver's protocol module).
ERROR_BITS = {
    1: ('input voltage', True),
    2: ('angle limit', False),
    4: ('overheating', True),
    8: ('range', False),
    16: ('checksum', False),
    32: ('overload', True),
    64: ('instruction', False),
}


@dataclass(frozen=True)
class Status:
    """One diagnostic_msgs/DiagnosticStatus as plain data."""

    level: int
    name: str
    message: str
    hardware_id: str
    values: tuple[tuple[str, str], ...]


def error_names(bits: int) -> list[str]:
    return [name for bit, (name, _) in ERROR_BITS.items() if bits & bit]


def _num(v: float | None, fmt: str) -> str:
    return 'unknown' if v is None or not math.isfinite(v) else format(v, fmt)


def servo_status(robot: Robot, node: str, joint: str, servo_id: int, *, temperature_c: float, voltage_v: float,
                 load_fraction: float, error_bits: int, responding: bool, torque_enabled: bool,
                 torque_limit: int | None = None, note: str = '') -> Status:
    """The status of one servo. ``torque_limit``: register 34 (0..1023, None unknown); ``note``: the
    driver's own text about it (fault policy, recovery), appended to the message."""
    shutdown = robot.servo.shutdown_temperature_c
    problems: list[tuple[int, str]] = []
    if not responding:
        problems.append((ERROR, 'not responding'))
    for bit, (name, stops) in ERROR_BITS.items():
        if error_bits & bit:
            problems.append((ERROR if stops else WARN, f'{name} error'))
    if torque_limit == 0:
        problems.append((ERROR, 'torque limit 0 (alarm shutdown: limp)'))
    elif not torque_enabled:
        problems.append((WARN, 'torque off'))
    if math.isfinite(temperature_c):
        if temperature_c >= shutdown:
            problems.append((ERROR, f'{temperature_c:.0f} C: at the shutdown temperature {shutdown:g} C'))
        elif temperature_c >= shutdown - TEMPERATURE_WARN_MARGIN_K:
            problems.append((WARN, f'{temperature_c:.0f} C: within {TEMPERATURE_WARN_MARGIN_K:g} K of shutdown'))
    level = max((lvl for lvl, _ in problems), default=OK)
    message = '; '.join(text for _, text in problems) or 'OK'
    if note and note != 'ok':
        message = f'{message} ({note})'
    limit = 'unknown' if torque_limit is None else f'{torque_limit / 1023:.0%}'
    values = (('joint', joint), ('id', str(servo_id)), ('temperature_c', _num(temperature_c, '.1f')),
              ('voltage_v', _num(voltage_v, '.1f')), ('load_percent', _num(100.0 * load_fraction, '.0f')),
              ('error_bits', f'0x{error_bits:02x}' + (f' ({", ".join(error_names(error_bits))})' if error_bits else '')),
              ('torque_enabled', str(bool(torque_enabled)).lower()), ('torque_limit', limit),
              ('responding', str(bool(responding)).lower()))
    return Status(level, f'{node}: servo {joint} (id {servo_id})', message, f'dynamixel id {servo_id}', values)


def bus_status(robot: Robot, node: str, *, window_s: float, reads: int, failed_reads: int, t_com_mean_s: float,
               t_com_p99_s: float, t_com_max_s: float, write_mean_s: float, note: str = '') -> Status:
    """Health of the bus over a window of ``window_s``: read rate, failures, T_com against the model's."""
    nominal = robot.bus.t_com_s
    problems: list[tuple[int, str]] = []
    attempts = reads + failed_reads
    if failed_reads and failed_reads >= attempts:
        problems.append((ERROR, f'all {failed_reads} reads failed'))
    elif failed_reads:
        problems.append((WARN, f'{failed_reads} of {attempts} reads failed'))
    if attempts == 0:
        problems.append((WARN, f'no read in {window_s:.1f} s'))
    if reads and math.isfinite(t_com_mean_s) and t_com_mean_s > T_COM_WARN_FACTOR * nominal:
        problems.append((WARN, f'T_com {t_com_mean_s * 1e3:.1f} ms, the model assumes {nominal * 1e3:g} ms'))
    if note:
        problems.append((ERROR, note))
    level = max((lvl for lvl, _ in problems), default=OK)
    rate = reads / window_s if window_s > 0 else math.nan
    values = (('read_rate_hz', _num(rate, '.1f')), ('reads', str(reads)), ('failed_reads', str(failed_reads)),
              ('t_com_mean_ms', _num(t_com_mean_s * 1e3, '.3f')), ('t_com_p99_ms', _num(t_com_p99_s * 1e3, '.3f')),
              ('t_com_max_ms', _num(t_com_max_s * 1e3, '.3f')), ('t_com_model_ms', _num(nominal * 1e3, 'g')),
              ('write_mean_ms', _num(write_mean_s * 1e3, '.3f')), ('window_s', _num(window_s, '.2f')))
    message = '; '.join(text for _, text in problems) or f'OK: {_num(rate, ".0f")} reads/s'
    return Status(level, f'{node}: bus', message, 'dynamixel bus', values)


def as_dict(status: Status) -> dict:
    """diagnostic_msgs/DiagnosticStatus as a plain dict (for bags)."""
    return {'level': status.level, 'name': status.name, 'message': status.message,
            'hardware_id': status.hardware_id, 'values': [{'key': k, 'value': v} for k, v in status.values]}


def array_dict(statuses, t_s: float) -> dict:
    """diagnostic_msgs/DiagnosticArray as a plain dict (for bags), stamped ``t_s``."""
    sec, nsec = stamp_parts(t_s)
    return {'header': {'stamp': {'sec': sec, 'nanosec': nsec}, 'frame_id': ''},
            'status': [as_dict(s) for s in statuses]}


def diagnostic_array(statuses, stamp):
    """diagnostic_msgs/DiagnosticArray of ``statuses`` with ``header.stamp = stamp`` (a builtin_interfaces Time)."""
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
    msg = DiagnosticArray()
    msg.header.stamp = stamp
    for s in statuses:
        msg.status.append(DiagnosticStatus(level=bytes([s.level]), name=s.name, message=s.message,
                                           hardware_id=s.hardware_id,
                                           values=[KeyValue(key=k, value=v) for k, v in s.values]))
    return msg
