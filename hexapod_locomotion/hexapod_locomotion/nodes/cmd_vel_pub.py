"""cmd_vel_pub: publish a fixed velocity command on ``cmd_vel`` - ``ros2 topic pub`` for this stack.

    ros2 run hexapod_locomotion cmd_vel_pub --vx 0.03 --duration 20
    ./hexapod cmd-vel --vx 0.03 --wz 0.05          # until Ctrl-C

Publishes ``geometry_msgs/Twist`` at ``--rate`` Hz (wall clock) for ``--duration`` seconds (0 = until
Ctrl-C or SIGTERM), then one zero Twist (the robot stands) and exits 0. With ``--wait-subscribers N``
(``ros2 topic pub -w``) it first waits until N subscribers match, so the duration counts commands
someone receives. The topic name is relative
(``cmd_vel``), so a namespace or ``--ros-args -r cmd_vel:=...`` applies. locomotion_node stops
walking when its last command is older than its ``cmd_vel_timeout_s``: keep ``--rate`` well above
1 / that timeout. Speeds are checked with the controller's own :class:`VelocityCommand` (finite);
the controller itself clamps the stride and the turn per cycle (``max_stride_m``, ``max_turn_rad``),
so a larger speed walks at the largest stride, not faster.

The rclpy-free parts (argument checks, signal flag) are shared with :mod:`.teleop_keyboard`.
"""
from __future__ import annotations

import argparse
import math
import signal
import sys
import threading
import time

from hexapod_locomotion.core.locomotion_params import LocomotionError, VelocityCommand
from hexapod_model.cli_common import make_parser, prog_name
from hexapod_model.contract import CMD_VEL

TOPIC = CMD_VEL        # relative: resolved in the node's namespace (--ros-args -r __ns:=/hexa)
ACK_TIMEOUT_S = 1.0    # wait this long for subscribers to acknowledge the final zero Twist


class CliError(Exception):
    """Bad command-line input; the message is the one line shown to the user."""


def check_velocity(vx: float, vy: float, wz: float) -> VelocityCommand:
    """The command as the controller would accept it; CliError names the flag it refuses."""
    for flag, name, value in (('--vx', 'vx', vx), ('--vy', 'vy', vy), ('--wz', 'wz', wz)):
        try:
            VelocityCommand(**{name: value})
        except LocomotionError as exc:
            raise CliError(f'{flag} {value}: {exc}') from None
    return VelocityCommand(vx, vy, wz)


def check_number(flag: str, value: float, *, positive: bool = False) -> float:
    """A finite value >= 0 (> 0 with ``positive``); CliError names the flag otherwise."""
    if not math.isfinite(value):
        raise CliError(f'{flag} must be a finite number, got {value}')
    if positive and value <= 0:
        raise CliError(f'{flag} must be > 0, got {value}')
    if value < 0:
        raise CliError(f'{flag} must be >= 0, got {value}')
    return value


def rate_warning(rate_hz: float, timeout_s: float) -> str | None:
    """Why a rate is too slow for a consumer that drops commands older than ``timeout_s``."""
    if 1.0 / rate_hz > timeout_s / 2:
        return (f'warning: --rate {rate_hz:g} Hz is slow for locomotion_node (cmd_vel_timeout_s = '
                f'{timeout_s:g} s by default): the robot may stop between messages; use >= {2 / timeout_s:g} Hz')
    return None


def controller_cmd_vel_timeout_s() -> float:
    """locomotion_node's default ``cmd_vel_timeout_s`` (read from its parameter schema, not retyped)."""
    from hexapod_locomotion.nodes.params import LocomotionNodeParams
    return LocomotionNodeParams().cmd_vel_timeout_s


class StopFlag:
    """SIGINT / SIGTERM / SIGHUP set a flag (main thread) instead of raising or killing the process,
    so the caller can still publish its final zero Twist while the ROS context is valid."""

    SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)

    def __init__(self):
        self.event = threading.Event()
        self.signum: int | None = None
        self._old = {s: signal.signal(s, self._handle) for s in self.SIGNALS}

    def _handle(self, signum, _frame):
        self.signum = signum
        self.event.set()

    def is_set(self) -> bool:
        return self.event.is_set()

    def restore(self) -> None:
        for s, h in self._old.items():
            signal.signal(s, h)


def twist(cmd: VelocityCommand):
    from geometry_msgs.msg import Twist
    m = Twist()
    m.linear.x, m.linear.y, m.angular.z = float(cmd.vx), float(cmd.vy), float(cmd.wz)
    return m


def user_args(argv: list[str]) -> list[str]:
    """argv[1:] without the --ros-args part (for argparse); malformed --ros-args raise CliError."""
    from rclpy._rclpy_pybind11 import RCLError
    from rclpy.utilities import remove_ros_args
    try:
        return remove_ros_args(argv)[1:]
    except RCLError as exc:
        raise CliError(f'bad --ros-args: {str(exc).splitlines()[0]}') from None


def start_ros(prog: str, argv: list[str], node_name: str):
    """rclpy.init without rclpy's signal handlers (StopFlag handles them) + a node with the
    cmd_vel publisher. Bad --ros-args or remaps raise CliError (one line)."""
    import rclpy
    from geometry_msgs.msg import Twist
    from rclpy._rclpy_pybind11 import RCLError
    from rclpy.exceptions import NameValidationException
    from rclpy.signals import SignalHandlerOptions

    try:
        rclpy.init(args=argv, signal_handler_options=SignalHandlerOptions.NO)
    except RCLError as exc:
        raise CliError(f'bad --ros-args: {str(exc).splitlines()[0]}') from None
    try:
        node = rclpy.create_node(node_name)
        pub = node.create_publisher(Twist, TOPIC, 10)
    except (RCLError, NameValidationException, ValueError) as exc:
        rclpy.try_shutdown()
        raise CliError(f'cannot publish {TOPIC}: {str(exc).splitlines()[0]}') from None
    return node, pub


def finish_ros(node, pub) -> bool:
    """Publish one zero Twist, wait for its acknowledgement, tear down. True if the zero went out."""
    import rclpy
    from rclpy.duration import Duration

    sent = False
    try:
        if node is not None and rclpy.ok():
            pub.publish(twist(VelocityCommand(0.0, 0.0, 0.0)))
            pub.wait_for_all_acked(Duration(seconds=ACK_TIMEOUT_S))
            sent = True
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    return sent


def parse_args(argv: list[str]) -> argparse.Namespace:
    ap = make_parser('cmd_vel_pub', 'Publish a fixed geometry_msgs/Twist on cmd_vel at a fixed rate, then a zero\n'
                                    'Twist. Also accepts --ros-args (e.g. -r cmd_vel:=/other).')
    ap.add_argument('--vx', type=float, default=0.0, help='forward speed [m/s]')
    ap.add_argument('--vy', type=float, default=0.0, help='leftward speed [m/s]')
    ap.add_argument('--wz', type=float, default=0.0, help='yaw rate, counter-clockwise [rad/s]')
    ap.add_argument('--rate', type=float, default=10.0, help='publishing rate [Hz], wall clock')
    ap.add_argument('--duration', type=float, default=0.0, help='publish this long [s]; 0 = until Ctrl-C')
    ap.add_argument('--wait-subscribers', type=int, default=0, metavar='N',
                    help='before publishing, wait (until Ctrl-C) for N matching subscribers; 0 = start at once')
    return ap.parse_args(argv)


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv if argv is None else argv)
    try:
        args = parse_args(user_args(argv))
        cmd = check_velocity(args.vx, args.vy, args.wz)
        rate = check_number('--rate', args.rate, positive=True)
        duration = check_number('--duration', args.duration)
        wait_n = int(check_number('--wait-subscribers', args.wait_subscribers))
    except CliError as exc:
        print(f'{prog_name("cmd_vel_pub")}: error: {exc}', file=sys.stderr)
        return 2
    warning = rate_warning(rate, controller_cmd_vel_timeout_s())
    if warning:
        print(f'cmd_vel_pub: {warning}', file=sys.stderr)

    from rclpy.clock import Clock, ClockType
    from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor

    stop = StopFlag()
    node = pub = None
    count = 0
    try:
        node, pub = start_ros('cmd_vel_pub', argv, 'cmd_vel_pub')
        msg = twist(cmd)
        executor = SingleThreadedExecutor()
        executor.add_node(node)
        if wait_n > 0:
            print(f'cmd_vel_pub: waiting for {wait_n} subscriber(s) on {pub.topic_name}', flush=True)
            while not stop.is_set() and pub.get_subscription_count() < wait_n:
                executor.spin_once(timeout_sec=0.1)

        def tick():
            nonlocal count
            pub.publish(msg)
            count += 1

        if not stop.is_set():      # Ctrl-C while waiting for subscribers: no motion command, only the zero
            tick()
        node.create_timer(1.0 / rate, tick, clock=Clock(clock_type=ClockType.STEADY_TIME))
        t_end = time.monotonic() + duration if duration > 0 else math.inf
        print(f'cmd_vel_pub: publishing vx={cmd.vx:g} m/s vy={cmd.vy:g} m/s wz={cmd.wz:g} rad/s on '
              f'{pub.topic_name} at {rate:g} Hz ' + (f'for {duration:g} s' if duration > 0 else 'until Ctrl-C'),
              flush=True)
        # signal handlers run between spin_once calls: at most 0.1 s late
        while not stop.is_set() and time.monotonic() < t_end:
            executor.spin_once(timeout_sec=min(0.1, max(0.0, t_end - time.monotonic())))
        executor.shutdown()
    except CliError as exc:
        print(f'{prog_name("cmd_vel_pub")}: error: {exc}', file=sys.stderr)
        return 2
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        sent = finish_ros(node, pub) if node is not None else False
        stop.restore()
    print(f'cmd_vel_pub: {count} command(s) sent' + (', then a zero Twist' if sent else ''), flush=True)
    return 0


if __name__ == '__main__':
    sys.exit(main())
