"""cmd_vel_pub and teleop_keyboard: the key mapping without ROS, then the installed console scripts
(what `ros2 run` starts) as processes, received by a subscriber here.

DDS stays on loopback (ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST) on a domain of its own. Time
limits below are failure bounds only; assertions are on message contents and order.
"""
import math
import os
import signal
import subprocess
import termios
import threading
import time
from pathlib import Path

import pytest

from hexapod_locomotion.core.gait import get_gait
from hexapod_locomotion.core.locomotion_params import LocomotionParams
from hexapod_locomotion.nodes.cmd_vel_pub import CliError, check_velocity, rate_warning
from hexapod_locomotion.nodes.teleop_keyboard import Teleop, controller_limits, keys_from_bytes

REPO = Path(__file__).resolve().parents[2]
DOMAIN_ID = 100 + os.getpid() % 40          # 100..139: this file's process tests
WAIT_S = 30.0                               # failure bound for discovery / delivery on a loaded machine


# ------------------------------------------------------------------ key mapping, no ROS ----

def test_keys_step_each_axis_and_stop_is_exact_zero():
    t = Teleop(lin_step=0.01, ang_step=0.1, max_lin=0.05, max_ang=0.5)
    for k in 'www':
        assert t.press(k)
    assert t.command().vx == pytest.approx(0.03)
    t.press('x')
    assert t.command().vx == pytest.approx(0.02)
    t.press('a'), t.press('a'), t.press('d'), t.press('a')
    assert t.command().wz == pytest.approx(0.2)
    t.press('j'), t.press('l'), t.press('l')
    assert t.command().vy == pytest.approx(-0.01)
    assert t.status() == 'vx +0.020 m/s   vy -0.010 m/s   wz +0.200 rad/s'
    t.press('?'), t.press('W')                 # unknown keys change nothing
    assert (t.command().vx, t.command().vy) == (pytest.approx(0.02), pytest.approx(-0.01))
    t.press('s')
    assert (t.command().vx, t.command().vy, t.command().wz) == (0.0, 0.0, 0.0)
    for k in 'wad':
        t.press(k)
    t.press(' ')
    assert (t.command().vx, t.command().wz) == (0.0, 0.0)


def test_keys_clamp_to_whole_steps_within_the_limit():
    t = Teleop(lin_step=0.01, ang_step=0.1, max_lin=0.03, max_ang=0.25)
    for _ in range(10):
        t.press('w'), t.press('l'), t.press('d')
    # 0.03 / 0.01 is 2.9999999999999996 in floats: still three steps
    assert t.command().vx == pytest.approx(0.03) and t.command().vy == pytest.approx(-0.03)
    assert t.command().wz == pytest.approx(-0.2)      # two steps; a third would exceed 0.25
    t.press('x')
    assert t.command().vx == pytest.approx(0.02)      # one press back from the limit, not ten


def test_quit_keys_stop_and_end():
    for k in ('q', '\x03', '\x04'):
        t = Teleop(0.01, 0.1, 0.05, 0.5)
        t.press('w')
        assert t.press(k) is False
        assert t.command().vx == 0.0


def test_escape_sequences_are_not_keys():
    assert keys_from_bytes(b'w') == ['w']
    assert keys_from_bytes(b'\x1b[Ds') == ['s']                 # arrow left, then s
    assert keys_from_bytes(b'a\x1b[1;5Cw\x1bOAx') == ['a', 'w', 'x']   # Ctrl+arrow (CSI), SS3 arrow
    assert keys_from_bytes(b'\x1bwq') == ['q']                   # Alt+w is not w
    assert keys_from_bytes(b'\x1b') == [] and keys_from_bytes(b' \xff') == [' ']


def test_teleop_refuses_bad_steps_and_limits():
    with pytest.raises(CliError, match='--lin-step'):
        Teleop(float('nan'), 0.1, 0.05, 0.5)
    with pytest.raises(CliError, match='--ang-step'):
        Teleop(0.01, 0.0, 0.05, 0.5)
    with pytest.raises(CliError, match='--max-lin 0.001 is below one step'):
        Teleop(0.01, 0.1, 0.001, 0.5)
    with pytest.raises(CliError, match='--max-ang'):
        Teleop(0.01, 0.1, 0.05, float('inf'))


def test_default_limits_are_where_the_controller_clamps():
    p = LocomotionParams()
    tripod = get_gait('tripod')                      # fewest phases: the shortest cycle
    lin, ang = controller_limits()
    assert lin == pytest.approx(p.stride_m(tripod) / p.cycle_s(tripod))
    assert ang == pytest.approx(p.turn_rad(tripod) / p.cycle_s(tripod))
    # a command at the limit is a full stride per cycle, not more
    assert lin * p.cycle_s(tripod) == pytest.approx(p.stride_m(tripod))


def test_velocity_check_is_the_controllers_and_names_the_flag():
    assert check_velocity(0.5, -0.1, 2.0).wz == 2.0     # no invented limits: the controller clamps
    for flag, args in (('--vx', (math.nan, 0, 0)), ('--vy', (0, math.inf, 0)), ('--wz', (0, 0, -math.inf))):
        with pytest.raises(CliError, match=f'^{flag} .*not finite'):
            check_velocity(*args)


def test_rate_warning_against_the_timeout():
    assert rate_warning(10.0, 1.0) is None
    assert '--rate 1 Hz' in rate_warning(1.0, 1.0)     # what `ros2 topic pub` sends by default


# --------------------------------------------------------------------- the real processes ----

rclpy = pytest.importorskip('rclpy')
from geometry_msgs.msg import Twist  # noqa: E402

from hexapod_testing import installed_executable, node_env, ros_probe  # noqa: E402


def executable(name):
    """The installed console script, found as `ros2 run hexapod_locomotion NAME` finds it."""
    path = installed_executable('hexapod_locomotion', name)
    assert os.access(path, os.X_OK), f'{path} missing: ./hexapod build'
    return path


def proc_env():
    return node_env(DOMAIN_ID)


@pytest.fixture(scope='module')
def ros():
    with ros_probe('teleop_test', DOMAIN_ID) as probe:
        yield probe


class Inbox:
    def __init__(self, ros, topic):
        self.node, self.ex = ros
        self.msgs = []
        self.sub = self.node.create_subscription(
            Twist, topic, lambda m: self.msgs.append((m.linear.x, m.linear.y, m.angular.z)), 100)

    def spin_until(self, cond, what, timeout=WAIT_S):
        deadline = time.monotonic() + timeout
        while not cond():
            assert time.monotonic() < deadline, f'timed out waiting for {what}; received {self.msgs[-5:]}'
            self.ex.spin_once(timeout_sec=0.05)

    def drain(self, seconds=0.5):
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            self.ex.spin_once(timeout_sec=0.05)

    def close(self):
        self.node.destroy_subscription(self.sub)


def run_pub(*args):
    return subprocess.run([executable('cmd_vel_pub'), *map(str, args)], env=proc_env(), capture_output=True,
                          text=True, timeout=WAIT_S)


def wait_and_collect(proc, inbox, timeout=WAIT_S):
    """Spin the inbox while the process runs, then a little after (late deliveries)."""
    deadline = time.monotonic() + timeout
    while proc.poll() is None:
        assert time.monotonic() < deadline, 'process did not exit'
        inbox.ex.spin_once(timeout_sec=0.05)
    inbox.drain()


@pytest.mark.realtime      # the publisher runs at 20 Hz of wall time for a wall-clock duration: a loaded machine gets fewer messages
def test_cmd_vel_pub_duration_then_zero(ros):
    inbox = Inbox(ros, '/cmd_vel')
    try:
        proc = subprocess.Popen([executable('cmd_vel_pub'), '--vx', '0.03', '--wz', '-0.05', '--rate', '20',
                                 '--duration', '3', '--wait-subscribers', '1'], env=proc_env(), stdout=subprocess.PIPE,
                                stderr=subprocess.PIPE, text=True)
        wait_and_collect(proc, inbox)
        out, err = proc.communicate(timeout=WAIT_S)
    finally:
        inbox.close()
    assert proc.returncode == 0, err
    assert 'Traceback' not in err
    assert 'on /cmd_vel at 20 Hz for 3 s' in out
    assert inbox.msgs, f'nothing received; {out} {err}'
    assert inbox.msgs[-1] == (0.0, 0.0, 0.0)                     # ends with a stop
    moving = inbox.msgs[:-1]
    assert len(moving) >= 2 and set(moving) == {(0.03, 0.0, -0.05)}
    sent = int(out.split('cmd_vel_pub: ')[-1].split()[0])      # "N command(s) sent, then a zero Twist"
    assert 'then a zero Twist' in out and len(moving) <= sent


@pytest.mark.parametrize('sig', [signal.SIGTERM, signal.SIGINT])
def test_cmd_vel_pub_until_signal_with_ros_args_remap(ros, sig):
    topic = f'/teleop_test/{sig.name.lower()}'
    inbox = Inbox(ros, topic)
    proc = subprocess.Popen([executable('cmd_vel_pub'), '--vy', '0.02', '--ros-args', '-r', f'cmd_vel:={topic}'],
                            env=proc_env(), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        inbox.spin_until(lambda: len(inbox.msgs) >= 3, 'three commands')
        proc.send_signal(sig)
        wait_and_collect(proc, inbox)
        out, err = proc.communicate(timeout=WAIT_S)
    finally:
        if proc.poll() is None:
            proc.kill()
        inbox.close()
    assert proc.returncode == 0, err
    assert 'Traceback' not in err and err.strip() == '', err
    assert f'on {topic} at 10 Hz until Ctrl-C' in out
    assert set(inbox.msgs[:-1]) == {(0.0, 0.02, 0.0)} and inbox.msgs[-1] == (0.0, 0.0, 0.0)


@pytest.mark.parametrize('args, flag', [
    (('--rate', 'nan'), '--rate'), (('--rate', '-1'), '--rate'), (('--rate', '0'), '--rate'),
    (('--duration', '-1'), '--duration'), (('--duration', 'inf'), '--duration'),
    (('--vx', 'inf'), '--vx'), (('--vy', 'nan'), '--vy'), (('--wz', '-inf'), '--wz'),
    (('--vx', 'fast'), '--vx'), (('--speed', '1'), '--speed'), (('--wait-subscribers', '-1'), '--wait-subscribers'),
])
def test_cmd_vel_pub_bad_flags(args, flag):
    res = run_pub(*args)
    assert res.returncode == 2
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and flag in lines[0] and lines[0].startswith('cmd_vel_pub: '), res.stderr
    assert res.stdout == ''


def test_cmd_vel_pub_bad_remap_is_one_line():
    res = run_pub('--duration', '1', '--ros-args', '-r', 'cmd_vel:=1bad name')
    assert res.returncode == 2, res.stderr
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and 'Traceback' not in res.stderr, res.stderr


# --------------------------------------------------------------- teleop on a pseudo-terminal ----

class Pty:
    """teleop_keyboard with a pseudo-terminal as stdin/stdout; the output is collected."""

    def __init__(self, *args, command=None):
        self.master, self.slave = os.openpty()
        self.saved = termios.tcgetattr(self.slave)
        command = command or [executable('teleop_keyboard')]
        self.proc = subprocess.Popen([*command, *args], env=proc_env(), stdin=self.slave,
                                     stdout=self.slave, stderr=subprocess.PIPE, close_fds=True)
        self.out = b''
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self):
        while True:
            try:
                data = os.read(self.master, 1024)
            except OSError:
                return
            if not data:
                return
            self.out += data

    def text(self):
        return self.out.decode(errors='replace')

    def send(self, keys):
        os.write(self.master, keys.encode())

    def close(self):
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait()
        os.close(self.slave)
        os.close(self.master)


def test_teleop_keys_over_a_pty(ros):
    inbox = Inbox(ros, '/cmd_vel')
    t = Pty('--lin-step', '0.01', '--ang-step', '0.1', '--max-lin', '0.02', '--max-ang', '1.0')
    try:
        # the status line is drawn once the terminal is raw; the first (zero) Twist proves discovery
        inbox.spin_until(lambda: 'vx +0.000' in t.text(), 'the status line')
        assert termios.tcgetattr(t.slave) != t.saved                 # raw while running
        inbox.spin_until(lambda: inbox.msgs, 'the first command')
        assert set(inbox.msgs) == {(0.0, 0.0, 0.0)}

        def expect(keys, cmd):
            t.send(keys)
            inbox.spin_until(lambda: inbox.msgs[-1] == pytest.approx(cmd), f'{cmd} after {keys!r}')

        expect('www', (0.02, 0.0, 0.0))                              # clamped at --max-lin
        expect('a', (0.02, 0.0, 0.1))
        expect('j', (0.02, 0.01, 0.1))
        assert 'vx +0.020 m/s   vy +0.010 m/s   wz +0.100 rad/s' in t.text()
        expect('x dd', (0.0, 0.0, -0.2))                             # stop in the middle of a burst
        expect('\x1b[Ds', (0.0, 0.0, 0.0))                            # arrow key ignored, not read as 'D'
        expect('l', (0.0, -0.01, 0.0))
        n_before_quit = len(inbox.msgs)
        t.send('q')
        wait_and_collect(t.proc, inbox)
        err = t.proc.stderr.read().decode()
        assert t.proc.returncode == 0, err
        assert 'Traceback' not in err
        assert len(inbox.msgs) > n_before_quit and inbox.msgs[-1] == (0.0, 0.0, 0.0)
        # every message was one of the commands the keys asked for, in order, no stray values
        allowed = [(0.0, 0.0, 0.0), (0.01, 0.0, 0.0), (0.02, 0.0, 0.0), (0.02, 0.0, 0.1), (0.02, 0.01, 0.1),
                   (0.01, 0.01, 0.1), (0.0, 0.0, 0.1), (0.0, 0.0, -0.1), (0.0, 0.0, -0.2), (0.0, -0.01, 0.0)]
        assert all(any(m == pytest.approx(a) for a in allowed) for m in inbox.msgs), inbox.msgs
        assert termios.tcgetattr(t.slave) == t.saved                 # terminal restored
        assert 'teleop_keyboard: stopped (zero Twist sent)' in t.text()
    finally:
        t.close()
        inbox.close()


def test_teleop_sigterm_restores_terminal_and_stops(ros):
    inbox = Inbox(ros, '/cmd_vel')
    t = Pty()
    try:
        inbox.spin_until(lambda: 'vx +0.000' in t.text(), 'the status line')
        t.send('w')
        inbox.spin_until(lambda: inbox.msgs and inbox.msgs[-1][0] > 0, 'a forward command')
        t.proc.send_signal(signal.SIGTERM)
        wait_and_collect(t.proc, inbox)
        err = t.proc.stderr.read().decode()
        assert t.proc.returncode == 0 and 'Traceback' not in err, err
        assert inbox.msgs[-1] == (0.0, 0.0, 0.0)
        assert termios.tcgetattr(t.slave) == t.saved
    finally:
        t.close()
        inbox.close()


def test_hexapod_teleop_gets_the_terminal(ros):
    """``./hexapod teleop`` hands the terminal to the program (the shortcut used to run it with the
    shortcut table as its standard input): it draws its status line, takes a key and quits on 'q'."""
    inbox = Inbox(ros, '/cmd_vel')
    t = Pty(command=[str(REPO / 'hexapod'), 'teleop'])
    try:
        inbox.spin_until(lambda: 'vx +0.000' in t.text() or t.proc.poll() is not None, 'the status line')
        assert t.proc.poll() is None, t.proc.stderr.read().decode()
        t.send('w')
        inbox.spin_until(lambda: inbox.msgs and inbox.msgs[-1][0] > 0, 'a forward command')
        t.send('q')
        wait_and_collect(t.proc, inbox)
        err = t.proc.stderr.read().decode()
        assert t.proc.returncode == 0 and 'Traceback' not in err and 'not a TTY' not in err, err
        assert inbox.msgs[-1] == (0.0, 0.0, 0.0)
        assert termios.tcgetattr(t.slave) == t.saved
    finally:
        t.close()
        inbox.close()


def test_teleop_without_a_terminal():
    res = subprocess.run([executable('teleop_keyboard')], env=proc_env(), stdin=subprocess.DEVNULL,
                         capture_output=True, text=True, timeout=WAIT_S)
    assert res.returncode == 2
    assert res.stderr.strip().splitlines() == [
        'teleop_keyboard needs a terminal: stdin is not a TTY; use cmd_vel_pub for scripts']


def test_teleop_bad_flag_is_one_line():
    res = subprocess.run([executable('teleop_keyboard'), '--rate', '-5'], env=proc_env(),
                         stdin=subprocess.DEVNULL, capture_output=True, text=True, timeout=WAIT_S)
    assert res.returncode == 2 and res.stderr.strip().splitlines() == ['teleop_keyboard: error: --rate must be > 0, got -5.0']


def test_teleop_bad_ros_args_is_one_line():
    res = subprocess.run([executable('teleop_keyboard'), '--ros-args', '-r', 'cmd_vel:=1bad name'], env=proc_env(),
                         stdin=subprocess.DEVNULL, capture_output=True, text=True, timeout=WAIT_S)
    assert res.returncode == 2 and len(res.stderr.strip().splitlines()) == 1, res.stderr
    assert res.stderr.startswith('teleop_keyboard: error: bad --ros-args: ')
