"""Replay: a replayed bag received by a subscriber equals the recording, in order, type, content
and timing; window/clock options; unknown types, truncated and garbage bags through the CLI."""
import os
import signal
import statistics
import subprocess
import sys
import threading
import time

import pytest

os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
DOMAIN_ID = 180 + os.getpid() % 40          # test-specific, away from ./hexapod test's 50..99
os.environ['ROS_DOMAIN_ID'] = str(DOMAIN_ID)

import rclpy  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.qos import QoSProfile  # noqa: E402
from rclpy.serialization import deserialize_message  # noqa: E402
from rosgraph_msgs.msg import Clock  # noqa: E402
from sensor_msgs.msg import Imu, JointState  # noqa: E402

from hexapod_model import contract  # noqa: E402
from hexapod_msgs.msg import ReadSchedule  # noqa: E402
from hexapod_sim.bagio import BagReader, BagWarning, BagWriter  # noqa: E402
from hexapod_sim.tools.replay import BagPlayer, Pacer, playback_window  # noqa: E402

T0 = 1_700_000_000_000_000_000
JS = 'sensor_msgs/msg/JointState'
CLASSES = {contract.bag_topic(t): cls for t, cls in ((contract.JOINT_STATES, JointState), (contract.IMU, Imu),
                                                     (contract.READ_SCHEDULE, ReadSchedule))}   # as the bag names them


def make_bag(path, n=90, seed_gap_ms=(4, 9, 15, 23)):
    """Three topics at irregular intervals (4..23 ms), ~1.1 s of bag time."""
    with BagWriter(path) as w:
        t = T0
        for i in range(n):
            t += seed_gap_ms[i % len(seed_gap_ms)] * 1_000_000
            stamp = contract.stamp_dict_ns(t)
            if i % 3 == 0:
                w.write(contract.JOINT_STATES, JS, {'header': {'stamp': stamp}, 'name': ['leg1_femur'],
                                                    'position': [0.01 * i]}, t)
            elif i % 3 == 1:
                w.write(contract.IMU, 'sensor_msgs/msg/Imu', {'header': {'stamp': stamp, 'frame_id': 'base'},
                                                             'linear_acceleration': {'z': 9.81 + i}}, t)
            else:
                w.write(contract.READ_SCHEDULE, 'hexapod_msgs/msg/ReadSchedule',
                        {'header': {'stamp': stamp}, 'joint_names': [f'leg{1 + i % 6}_femur']}, t)
    return path


@pytest.fixture(scope='module')
def ros():
    rclpy.init(domain_id=DOMAIN_ID)
    yield
    rclpy.try_shutdown()


class Receiver:
    """Subscribes (raw CDR) to the given topics; records (topic, bytes, monotonic receive time)."""

    def __init__(self, topics, clock=False):
        self.node = rclpy.create_node('replay_test_receiver')
        self.got, self.clock = [], []
        for topic in topics:
            self.node.create_subscription(CLASSES[topic], topic, self._cb(topic), QoSProfile(depth=1000), raw=True)
        if clock:
            self.node.create_subscription(Clock, contract.CLOCK, lambda m: self.clock.append(m), 100)
        self.ex = SingleThreadedExecutor()
        self.ex.add_node(self.node)
        self._stop = False
        self.thread = threading.Thread(target=self._spin, daemon=True)
        self.thread.start()

    def _cb(self, topic):
        def cb(data):
            self.got.append((topic, bytes(data), time.monotonic()))
        return cb

    def _spin(self):
        while not self._stop:
            self.ex.spin_once(timeout_sec=0.05)

    def wait_for(self, n, timeout=10.0):
        end = time.monotonic() + timeout
        while len(self.got) < n and time.monotonic() < end:
            time.sleep(0.01)

    def close(self):
        self._stop = True
        self.thread.join(5)
        self.ex.remove_node(self.node)
        self.node.destroy_node()


def play(reader, rx, **kw):
    player = BagPlayer(reader, **kw)
    try:
        assert player.wait_for_subscribers(15.0), 'receiver not discovered'
        # both ends matched (not only the player's view of the receiver): no first message is lost
        deadline = time.monotonic() + 15.0
        while not all(rx.node.count_publishers(t) > 0 for t in player.playable_topics):
            assert time.monotonic() < deadline, 'player not discovered by the receiver'
            time.sleep(0.01)
        return player.play()
    finally:
        player.destroy_node()


def test_replay_reproduces_messages_in_order(ros, tmp_path):
    reader = BagReader(make_bag(tmp_path / 'bag'))
    recorded = list(reader.messages(raw=True))
    rx = Receiver(reader.topics())
    try:
        stats = play(reader, rx, rate=4.0)
        rx.wait_for(len(recorded))
    finally:
        rx.close()
    assert stats.total == len(recorded)
    # type and content: byte-identical CDR; order: exactly the recorded order on every topic (DDS
    # orders per topic only: two topics' messages 2 ms apart may be dispatched in either order)
    assert sorted((t, d) for t, d, _ in rx.got) == sorted((m.topic, m.msg) for m in recorded)
    for topic in reader.topics():
        assert [d for t, d, _ in rx.got if t == topic] == [m.msg for m in recorded if m.topic == topic]
    decoded = {m.topic: deserialize_message(m.msg, CLASSES[m.topic]) for m in recorded}
    assert decoded[contract.bag_topic(contract.READ_SCHEDULE)].joint_names[0].startswith('leg')


@pytest.mark.realtime
@pytest.mark.parametrize('rate', [1.0, 2.0])
def test_replay_reproduces_messages_and_timing(ros, tmp_path, rate):
    """Wall-clock playback is what replay is for: receive times against the recorded schedule."""
    reader = BagReader(make_bag(tmp_path / 'bag'))
    recorded = list(reader.messages(raw=True))
    rx = Receiver(reader.topics())
    try:
        stats = play(reader, rx, rate=rate)
        rx.wait_for(len(recorded))
    finally:
        rx.close()
    assert stats.total == len(recorded) and len(rx.got) == len(recorded)
    # timing: receive time vs the recorded schedule scaled by 1/rate (constant latency removed)
    t_of = {(m.topic, m.msg): m.t_ns for m in recorded}
    pairs = sorted(((t_of[(t, d)] - recorded[0].t_ns) * 1e-9 / rate, r) for t, d, r in rx.got)
    sched = [s for s, _ in pairs]
    recv = [r for _, r in pairs]
    offset = statistics.median(r - s for r, s in zip(recv, sched))
    dev = [abs(r - s - offset) for r, s in zip(recv, sched)]
    assert statistics.median(dev) < 0.005, f'median deviation {statistics.median(dev) * 1e3:.2f} ms'
    gaps = [abs((recv[i + 1] - recv[i]) - (sched[i + 1] - sched[i])) for i in range(len(recv) - 1)]
    assert statistics.median(gaps) < 0.005
    span_err = abs((recv[-1] - recv[0]) - sched[-1])     # no drift over the whole bag
    assert span_err < 0.05 + 0.1 * sched[-1], span_err


def test_window_and_clock(ros, tmp_path):
    reader = BagReader(make_bag(tmp_path / 'bag'))
    begin, end = playback_window(reader, 0.3, 0.4)
    want = [m for m in reader.messages(raw=True) if begin <= m.t_ns < end]
    rx = Receiver(reader.topics(), clock=True)
    try:
        stats = play(reader, rx, rate=2.0, start_s=0.3, duration_s=0.4, clock_hz=50.0)
        rx.wait_for(len(want))
        deadline = time.monotonic() + 10.0           # failure bound: every /clock published arrives
        while len(rx.clock) < stats.clock_published and time.monotonic() < deadline:
            time.sleep(0.01)
    finally:
        rx.close()
    assert sorted((t, d) for t, d, _ in rx.got) == sorted((m.topic, m.msg) for m in want)
    for topic in reader.topics():
        assert [d for t, d, _ in rx.got if t == topic] == [m.msg for m in want if m.topic == topic]
    clocks = [contract.stamp_ns(c.clock) for c in rx.clock]
    assert stats.clock_published >= 5 and len(clocks) >= 5          # 0.2 s wall at 50 Hz
    assert clocks == sorted(clocks) and begin <= clocks[0] and clocks[-1] <= end
    with pytest.raises(ValueError, match='past the end of the bag'):
        playback_window(reader, 100.0, None)


def test_pacer_uses_absolute_deadlines():
    p = Pacer(bag0_ns=5_000_000_000, rate=2.0, wall0=100.0)
    assert p.deadline(5_000_000_000) == 100.0
    assert p.deadline(7_000_000_000) == pytest.approx(101.0)          # 2 s of bag at rate 2
    assert p.bag_time(101.5) == 8_000_000_000
    # the deadline of message k depends only on its own stamp: no accumulated error
    ts = [5_000_000_000 + k * 1_000_003 for k in range(100000)]
    assert p.deadline(ts[-1]) == pytest.approx(100.0 + (ts[-1] - ts[0]) * 1e-9 / 2.0, abs=1e-12)
    with pytest.raises(ValueError):
        Pacer(0, 0.0, 0.0)


# ------------------------------------------------------------------------------------ CLI ----

def run_cli(*args, timeout=60):
    env = dict(os.environ, ROS_DOMAIN_ID=str(DOMAIN_ID), ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST')
    return subprocess.run([sys.executable, '-m', 'hexapod_sim.tools.replay', *map(str, args)], env=env,
                          capture_output=True, text=True, timeout=timeout)


def test_cli_unknown_type_and_truncated_bag(tmp_path):
    bag = tmp_path / 'mixed'
    with BagWriter(bag, chunk_size=600) as w:
        w.add_topic('/widget', 'acme_msgs/msg/Widget', definition='float64 level\n')
        for i in range(60):
            t = T0 + i * 2_000_000
            w.write(contract.JOINT_STATES, JS, {'position': [float(i)]}, t)
            w.write('/widget', 'acme_msgs/msg/Widget', {'level': float(i)}, t + 1)
    res = run_cli(bag, '--rate', '10')
    assert res.returncode == 0, res.stderr
    assert 'skipping /widget: message type acme_msgs/msg/Widget unknown here' in res.stderr
    assert "published 60 message(s)" in res.stdout and "'/joint_states': 60" in res.stdout
    # cut the file in the middle: plays what is complete, with a warning
    mcap = bag / 'mixed_0.mcap'
    data = mcap.read_bytes()
    mcap.write_bytes(data[:len(data) // 2])
    with pytest.warns(BagWarning):
        recovered = sum(m.topic == contract.bag_topic(contract.JOINT_STATES) for m in BagReader(bag).messages())
    assert 0 < recovered < 60
    res = run_cli(bag, '--rate', '10')
    assert res.returncode == 0, res.stderr
    assert 'truncated' in res.stderr and f"'/joint_states': {recovered}" in res.stdout
    assert res.stderr.count('truncated') == 1, res.stderr          # the warning once, not also as a Python warning


def test_cli_garbage_and_bad_options(tmp_path):
    junk = tmp_path / 'junk.mcap'
    junk.write_bytes(os.urandom(1000))
    res = run_cli(junk)
    assert res.returncode == 2 and 'not an MCAP file' in res.stderr and 'Traceback' not in res.stderr
    res = run_cli(tmp_path / 'nope')
    assert res.returncode == 2 and 'no such file or directory' in res.stderr
    bag = make_bag(tmp_path / 'bag', n=6)
    for flag, value, want in (('--rate', '0', '> 0'), ('--duration', 'nan', '> 0'), ('--delay', 'nan', '>= 0'),
                              ('--wait-for-subscribers', '-1', '>= 0'), ('--qos-depth', '0', '>= 1')):
        res = run_cli(bag, flag, value)       # refused while parsing, before ROS starts
        assert res.returncode == 2 and f'argument {flag}: must be' in res.stderr and want in res.stderr, res.stderr
        assert len(res.stderr.strip().splitlines()) == 1
    res = run_cli(bag, '--topics', '/nope')
    assert res.returncode == 2 and "['/nope'] not in the bag" in res.stderr


def test_cli_ctrl_c_stops_cleanly(tmp_path):
    bag = make_bag(tmp_path / 'bag')
    env = dict(os.environ, ROS_DOMAIN_ID=str(DOMAIN_ID), ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST')
    proc = subprocess.Popen([sys.executable, '-m', 'hexapod_sim.tools.replay', str(bag), '--loop'], env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        line = proc.stdout.readline()          # "replay: playing ..." once it is publishing
        assert 'playing' in line, line + proc.stderr.read()
        proc.send_signal(signal.SIGINT)             # --loop: it is always in the middle of playing
        out, err = proc.communicate(timeout=15)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, err
    assert 'Traceback' not in err
