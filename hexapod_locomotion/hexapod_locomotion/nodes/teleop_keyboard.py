"""teleop_keyboard: drive the robot from the keyboard (like teleop_twist_keyboard), on ``cmd_vel``.

    ros2 run hexapod_locomotion teleop_keyboard
    ./hexapod teleop

Keys (single presses, no Enter): ``w``/``x`` forward/back one step, ``a``/``d`` turn left/right,
``j``/``l`` strafe left/right, ``s`` or space stop, ``q`` (or Ctrl-C, Ctrl-D) quit. The current
command is published from a timer at ``--rate`` Hz whether or not a key is pressed, so
locomotion_node's ``cmd_vel_timeout_s`` never stops the robot while this runs; on exit one zero
Twist is published and the terminal is restored.

Each speed is a whole number of steps, limited to ``--max-lin`` / ``--max-ang``: by default the
speeds at which the controller starts clamping the stride and turn per cycle (``max_stride_m``,
``max_turn_rad`` over the shortest gait cycle at default timings) - a faster command walks no
faster. The key handling (:class:`Teleop`) has no ROS in it.
"""
from __future__ import annotations

import argparse
import math
import os
import select
import sys
import threading
from dataclasses import dataclass

from hexapod_locomotion.core.gait import load_gaits
from hexapod_locomotion.core.locomotion_params import LocomotionParams, VelocityCommand
from hexapod_locomotion.nodes.cmd_vel_pub import CliError, StopFlag, check_number, finish_ros, start_ros, twist, user_args
from hexapod_model.cli_common import make_parser, prog_name

# key -> (axis, direction)
MOVES = {'w': ('vx', +1), 'x': ('vx', -1),
         'a': ('wz', +1), 'd': ('wz', -1),
         'j': ('vy', +1), 'l': ('vy', -1)}
STOP_KEYS = frozenset('s ')
QUIT_KEYS = frozenset('q\x03\x04')          # raw mode delivers Ctrl-C / Ctrl-D as characters

HELP = """teleop_keyboard: publishing on {topic} at {rate:g} Hz
  w/x : forward/back  {lin:g} m/s per press    j/l : strafe left/right
  a/d : turn left/right  {ang:g} rad/s per press
  s or space : stop      q : quit"""


def controller_limits() -> tuple[float, float]:
    """(|v| m/s, |wz| rad/s) beyond which the controller clamps, for the fastest packaged gait at
    the default LocomotionParams."""
    p = LocomotionParams()
    return max(p.saturating_velocity(g) for g in load_gaits().values())


@dataclass
class Teleop:
    """Keyboard state: each axis is an integer number of steps, so stopping is an exact zero."""

    lin_step: float
    ang_step: float
    max_lin: float
    max_ang: float

    def __post_init__(self):
        for flag, v in (('--lin-step', self.lin_step), ('--ang-step', self.ang_step)):
            check_number(flag, v, positive=True)
        for flag, v, step in (('--max-lin', self.max_lin, self.lin_step), ('--max-ang', self.max_ang, self.ang_step)):
            check_number(flag, v)
            if v < step:
                raise CliError(f'{flag} {v:g} is below one step ({step:g}): no key could move the robot')
        # the largest number of steps within the limit (tolerant of 0.03 / 0.01 = 2.9999999999999996)
        self._max_n = {'vx': math.floor(self.max_lin / self.lin_step + 1e-9),
                       'vy': math.floor(self.max_lin / self.lin_step + 1e-9),
                       'wz': math.floor(self.max_ang / self.ang_step + 1e-9)}
        self.n = {'vx': 0, 'vy': 0, 'wz': 0}

    def press(self, key: str) -> bool:
        """Apply one key; False means quit. Unknown keys change nothing."""
        if key in QUIT_KEYS:
            self.stop()
            return False
        if key in STOP_KEYS:
            self.stop()
        elif key in MOVES:
            axis, sign = MOVES[key]
            self.n[axis] = max(-self._max_n[axis], min(self._max_n[axis], self.n[axis] + sign))
        return True

    def stop(self) -> None:
        self.n = {'vx': 0, 'vy': 0, 'wz': 0}

    def command(self) -> VelocityCommand:
        return VelocityCommand(self.n['vx'] * self.lin_step, self.n['vy'] * self.lin_step,
                               self.n['wz'] * self.ang_step)

    def status(self) -> str:
        c = self.command()
        return f'vx {c.vx:+.3f} m/s   vy {c.vy:+.3f} m/s   wz {c.wz:+.3f} rad/s'


def keys_from_bytes(data: bytes) -> list[str]:
    """The key presses in one terminal read: escape sequences (arrows, function keys: CSI
    ``ESC [ params final``, SS3 ``ESC O final``; Alt+key ``ESC key``) are dropped whole, so their
    letters are not read as commands; the keys around them are kept."""
    text = data.decode('utf-8', errors='ignore')
    keys, i = [], 0
    while i < len(text):
        if text[i] != '\x1b':
            keys.append(text[i])
            i += 1
            continue
        i += 1
        if i < len(text) and text[i] in '[O':
            i += 1
            while i < len(text) and not '\x40' <= text[i] <= '\x7e':     # parameter bytes
                i += 1
        i += 1                                                          # final byte / Alt'd key
    return keys


def parse_args(argv: list[str]) -> argparse.Namespace:
    max_lin, max_ang = controller_limits()
    ap = make_parser('teleop_keyboard',
                     'Drive the robot from the keyboard on cmd_vel (needs a terminal; for scripts\n'
                     'use ./hexapod cmd-vel). Keys: w/x forward/back, a/d turn, j/l strafe, s or space '
                     'stop, q quit. Also accepts --ros-args (e.g. -r cmd_vel:=/other).')
    ap.add_argument('--lin-step', type=float, default=0.005, help='vx / vy change per key press [m/s]')
    ap.add_argument('--ang-step', type=float, default=0.02, help='wz change per key press [rad/s]')
    ap.add_argument('--max-lin', type=float, default=round(max_lin, 4),
                    help='largest |vx|, |vy| [m/s]; default: where the controller clamps the stride')
    ap.add_argument('--max-ang', type=float, default=round(max_ang, 4),
                    help='largest |wz| [rad/s]; default: where the controller clamps the turn')
    ap.add_argument('--rate', type=float, default=10.0, help='publishing rate [Hz], wall clock')
    return ap.parse_args(argv)


def _show(text: str) -> None:
    sys.stdout.write('\r\x1b[K' + text)
    sys.stdout.flush()


def _start_publishing(node, pub, teleop: Teleop, rate: float, lock: threading.Lock,
                      done: threading.Event) -> threading.Thread:
    """Publish the teleop's command at ``rate`` (steady clock) from a thread spinning ``node`` until
    ``done``; returns the started thread."""
    import rclpy
    from rclpy.clock import Clock, ClockType
    from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor

    def tick():
        with lock:
            msg = twist(teleop.command())
        pub.publish(msg)

    node.create_timer(1.0 / rate, tick, clock=Clock(clock_type=ClockType.STEADY_TIME))
    executor = SingleThreadedExecutor()
    executor.add_node(node)

    def spin():
        try:
            while not done.is_set() and rclpy.ok():
                executor.spin_once(timeout_sec=0.1)
        except ExternalShutdownException:
            pass

    spinner = threading.Thread(target=spin, name='teleop_spin', daemon=True)
    spinner.start()
    return spinner


def _read_keys(fd: int, teleop: Teleop, lock: threading.Lock, stop: StopFlag) -> None:
    """Apply the keys typed on the raw terminal ``fd`` until a quit key, a signal or the terminal's end."""
    _show(teleop.status())
    running = True
    while running and not stop.is_set():
        ready, _, _ = select.select([fd], [], [], 0.1)
        if not ready:
            continue
        data = os.read(fd, 64)
        if not data:                       # terminal closed
            break
        for key in keys_from_bytes(data):
            with lock:
                running = teleop.press(key)
            if not running:
                break
        _show(teleop.status())


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv if argv is None else argv)
    try:
        args = parse_args(user_args(argv))
        teleop = Teleop(args.lin_step, args.ang_step, args.max_lin, args.max_ang)
        rate = check_number('--rate', args.rate, positive=True)
    except CliError as exc:
        print(f'{prog_name("teleop_keyboard")}: error: {exc}', file=sys.stderr)
        return 2
    fd = sys.stdin.fileno()
    if not os.isatty(fd):
        print('teleop_keyboard needs a terminal: stdin is not a TTY; use cmd_vel_pub for scripts',
              file=sys.stderr)
        return 2

    import termios
    import tty

    from rclpy.executors import ExternalShutdownException

    stop = StopFlag()
    lock = threading.Lock()
    node = pub = None
    spinner = None
    done = threading.Event()
    saved = termios.tcgetattr(fd)
    try:
        node, pub = start_ros('teleop_keyboard', argv, 'teleop_keyboard')
        spinner = _start_publishing(node, pub, teleop, rate, lock, done)
        print(HELP.format(topic=pub.topic_name, rate=rate, lin=teleop.lin_step, ang=teleop.ang_step), flush=True)
        tty.setraw(fd)
        _read_keys(fd, teleop, lock, stop)
    except CliError as exc:
        print(f'{prog_name("teleop_keyboard")}: error: {exc}', file=sys.stderr)
        return 2
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        termios.tcsetattr(fd, termios.TCSADRAIN, saved)
        with lock:
            teleop.stop()
        done.set()
        if spinner is not None:
            spinner.join()
        sent = finish_ros(node, pub) if node is not None else False
        stop.restore()
    print('\nteleop_keyboard: stopped' + (' (zero Twist sent)' if sent else ''), flush=True)
    return 0


if __name__ == '__main__':
    sys.exit(main())
