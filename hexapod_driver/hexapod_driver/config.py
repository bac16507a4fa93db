"""The driver's settings: one dataclass per group, each field a node parameter with its description,
allowed range or choices (:mod:`hexapod_model.param_schema`). No ROS import: the bus library, the
``--help`` text, the node and the launch-file test all read the rules from here.

What the model must know too is not a setting of the driver but of the robot description
(robot.yaml + overlays), which model and sim read as well: servo mounting (``bus.joints``: ID,
direction, offset of each joint), the baud rate (``bus.baud_rate``) and the compliance margin and
slope written to the servos (``servo``: the swing-down model's P gain).
"""
from __future__ import annotations

from dataclasses import dataclass

from hexapod_model.param_schema import NodeSpec, RobotSource, param, validate

DEFAULT_DEVICE = '/dev/hexapod_dynamixel'     # the udev symlink of docs/real-robot.md
FAULT_POLICIES = ('limp', 'recover')
LIMIT_POLICIES = ('clamp', 'reject')


def _no_hold(value) -> str | None:
    if value == 'hold':
        return ("'hold' no longer exists: an AX-12A in alarm shutdown has zeroed its own torque limit, so "
                "nothing can hold the joint; use 'limp' or 'recover'")
    return None


def _non_empty(value) -> str | None:
    return None if value else 'must name the serial device, got an empty string'


@dataclass(frozen=True)
class DriverConfig:
    """Settings of :class:`hexapod_driver.bus.DynamixelBus` (the node's parameters)."""

    device: str = param(DEFAULT_DEVICE, 'serial device of the Dynamixel adapter (udev symlink, or the bus '
                        'emulator pty)', rule=_non_empty)
    latency_timer_ms: float = param(
        1.0, 'USB adapter latency timer [ms] (udev sets 1); sizes the reply timeout. Too small: replies are '
        'declared lost; too large: a lost reply blocks the bus longer. Widened automatically when start-up '
        'measures later replies', min=0.0)
    timeout_margin_ms: float = param(5.0, 'extra reply timeout [ms] for host scheduling jitter; too small: '
                                     'replies delayed by the host count as lost', min=0.0)
    startup_timeout_margin_ms: float = param(50.0, 'the same during start-up verification/configuration [ms]',
                                             min=0.0)
    startup_attempts: int = param(5, 'tries per transaction during start-up (a noisy bus) before start-up '
                                  'gives up and names what failed', min=1)
    return_delay_time: int = param(0, 'servo return delay (register 5, x 2 us) written at start-up; the '
                                   'factory 250 adds 0.5 ms to every read', min=0, max=254)
    torque_limit: int = param(1023, 'torque limit (register 34) written at start-up and on recovery; 0 would '
                              'leave the servos limp', min=1, max=1023)
    write_angle_limits: bool = param(True, 'write the joint limits as EEPROM angle limits (the servo then '
                                     'refuses goals outside them itself)')
    read_retries: int = param(2, 'extra attempts per failed read before it counts as failed', min=0)
    missing_after_failures: int = param(3, 'consecutive failed reads before a servo is skipped', min=1)
    reprobe_period_s: float = param(1.0, 'how often a skipped (silent) servo is tried again [s]',
                                    min=0.0, min_exclusive=True)
    reconnect_period_s: float = param(0.5, 'how often a lost serial port is reopened [s]',
                                      min=0.0, min_exclusive=True)
    command_timeout_s: float = param(1.0, 'commands stamped older than this are rejected, and with no '
                                     'command for this long the driver holds position [s]; 0 disables', min=0.0)
    limit_policy: str = param('clamp', 'goals outside the joint limits: clamped or rejected',
                              choices=LIMIT_POLICIES)
    fault_policy: str = param(
        'limp', "on overheating/overload, after the servo's own alarm shutdown has zeroed its torque limit: "
        'limp (also torque enable 0, joint out until restart) or recover (restore the torque limit at the '
        'present position once the alarm clears)', choices=FAULT_POLICIES, rule=_no_hold)
    diagnostics_period_s: float = param(1.0, 'period of a diagnostics round over all servos [s]',
                                        min=0.0, min_exclusive=True)
    read_period_s: float = param(0.0, "minimum spacing of position reads [s]; the node's default: the "
                                 "description's t_com_s, the read period the swing-down model assumes; "
                                 '0 = back to back (bus-limited)', min=0.0)

    def validate(self) -> None:
        """Raise :class:`hexapod_model.param_schema.ParameterError` naming the first bad setting."""
        validate(self)


@dataclass(frozen=True)
class DriverNodeParams:
    """What only the ROS node has: its publishers' periods and its lifecycle at start-up."""

    timing_period_s: float = param(1.0, 'period of /bus_timing messages [s]', min=0.0, min_exclusive=True)
    watchdog_timeout_s: float = param(
        2.0, 'report an ERROR (log and /servo_diagnostics) when no bus transaction has completed for this '
        'long [s]; 0 disables', min=0.0)
    autostart: bool = param(
        True, 'go through configure and activate at start-up (torque on, as a plain driver does); false: '
        'stay unconfigured until the lifecycle services (/<node>/change_state) are called')


def robot_defaults(robot) -> dict:
    """The default the description sets: reads paced at the read period the swing-down model assumes."""
    return {'read_period_s': robot.bus.t_com_s}


NODE = NodeSpec('hexapod_driver', 'driver_node', 'hexapod_driver', (RobotSource, DriverConfig, DriverNodeParams),
                robot_defaults)
