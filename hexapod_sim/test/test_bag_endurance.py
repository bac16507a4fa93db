"""Recordings that end badly: a write error in the running node, hard kills of the recording
processes. The bags they leave open in this project's reader and in ``rosbags``."""
from __future__ import annotations

import os
import random
import resource
import signal
import subprocess
import sys
import time
import warnings
from pathlib import Path

import pytest

from hexapod_sim.bagio import BagError, BagReader, BagWarning, BagWriter
from hexapod_sim.bagio.repair import reindex_bag
from hexapod_sim.bench.kill_bench import command, kill_one, rosbags_read
from hexapod_testing import node_env

FSIZE_LIMIT = 400_000      # bytes: the sim node's bag (~150 kB per second of sim time) hits it within seconds


def _limit_file_size():
    # What `ulimit -f` does; the writer then gets EFBIG (Python ignores SIGXFSZ, said again here). The node
    # gets a process group (and sid) of its own, as a terminal would give it.
    os.setsid()
    signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
    resource.setrlimit(resource.RLIMIT_FSIZE, (FSIZE_LIMIT, resource.RLIM_INFINITY))


def _read_both(bag: Path):
    with warnings.catch_warnings():
        warnings.simplefilter('ignore', BagWarning)
        reader = BagReader(bag)
    ok, n, why = rosbags_read(bag)
    assert ok, why
    assert n == reader.message_count
    return reader


def _wait_for_line(proc, needle: str, lines: list, timeout_s: float = 120.0) -> bool:
    """Read ``proc``'s stderr into ``lines`` until a line holds ``needle`` (the bound is a failure bound only)."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        line = proc.stderr.readline()
        if not line:
            return False
        lines.append(line.rstrip())
        if needle in line:
            return True
    return False


@pytest.mark.parametrize('stop', [False, True], ids=['carry_on', 'stop'])
def test_a_write_error_in_the_running_sim_node_is_one_line_and_the_bag_stays_readable(tmp_path, stop):
    bag = tmp_path / 'full'
    cmd = command('sim', bag) + ['-p', f'stop_on_record_error:={str(stop).lower()}']
    proc = subprocess.Popen(cmd, env=node_env(154 + stop), stderr=subprocess.PIPE, stdout=subprocess.DEVNULL,
                            text=True, preexec_fn=_limit_file_size)
    lines: list[str] = []
    try:
        assert _wait_for_line(proc, 'recording stopped', lines), '\n'.join(lines)
        if not stop:
            assert proc.poll() is None, '\n'.join(lines)        # the node runs on
            proc.send_signal(signal.SIGINT)
        _, rest = proc.communicate(timeout=60)
        lines += rest.splitlines()
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    text = '\n'.join(lines)
    failed = [x for x in lines if 'recording stopped' in x]
    assert len(failed) == 1 and str(bag) in failed[0] and 'File too large' in failed[0], text
    assert 'Traceback' not in text
    if stop:
        assert proc.returncode == 1, text
        assert 'torque off on every servo' in failed[0], text
    else:
        assert proc.returncode == 0, text
        assert 'runs on without recording' in failed[0], text
        assert any('bag closed' in x and 'recording had stopped on the error above' in x for x in lines), text
    reader = _read_both(bag)                                   # readable up to the error, by both readers
    assert reader.complete
    assert reader.message_count > 1000
    kept_s = (reader.end_ns - reader.start_ns) * 1e-9
    assert 0.5 < kept_s < 10.0                                 # a few seconds of sim time at ~150 kB/s


def test_a_write_error_ends_the_bag_at_its_last_flush(tmp_path):
    """The library alone: with the file-size limit of a child process, every write after the error
    raises the same one-line BagError, and the bag holds what was flushed before it."""
    script = f'''
import resource, sys
from hexapod_sim.bagio import BagWriter, BagError
resource.setrlimit(resource.RLIMIT_FSIZE, (60_000, resource.RLIM_INFINITY))
w = BagWriter({str(tmp_path / "b")!r}, compression='none', flush_period_s=0.2)
errors = []
for i in range(20_000):
    try:
        w.write('/joint_states', 'sensor_msgs/msg/JointState', {{'header': {{'stamp': {{'sec': i // 1000,
                'nanosec': (i % 1000) * 10**6}}}}, 'name': ['a'], 'position': [float(i)]}}, i * 10**6)
    except BagError as exc:
        errors.append(str(exc))
w.close()
print(len(errors), len(set(errors)))
print(errors[0])
'''
    p = subprocess.run([sys.executable, '-c', script], capture_output=True, text=True, timeout=120)
    assert p.returncode == 0, p.stderr
    counts, first = p.stdout.splitlines()
    count, distinct = counts.split()
    assert int(count) > 1000 and distinct == '1'
    assert first.startswith(str(tmp_path / 'b')) and 'write failed (File too large)' in first
    reader = _read_both(tmp_path / 'b')
    assert reader.complete and reader.message_count >= 200
    stamps = [m.t_ns for m in reader.messages()]
    assert stamps == [i * 10**6 for i in range(len(stamps))]      # the first messages, none missing


def test_reindex_rebuilds_a_cut_off_bag_that_rosbags_refuses(tmp_path):
    bag = tmp_path / 'cut'
    w = BagWriter(bag, flush_period_s=0.5)
    for i in range(3000):
        w.write('/joint_states', 'sensor_msgs/msg/JointState', {'header': {'stamp': {'sec': i // 1000,
                'nanosec': (i % 1000) * 10**6}}, 'name': ['a'], 'position': [float(i)]}, i * 10**6)
    w.flush()                             # the file as a power cut leaves it: no summary, no footer
    ok, _, why = rosbags_read(bag)
    assert not ok and 'magic' in why
    res = reindex_bag(bag)
    assert res.rebuilt and res.messages == 3000
    reader = _read_both(bag)
    assert reader.complete and [m.t_ns for m in reader.messages()] == [i * 10**6 for i in range(3000)]
    assert sorted(p.name for p in bag.iterdir()) == ['cut_0.mcap', 'metadata.yaml']
    assert not reindex_bag(bag).rebuilt   # complete now: left as it is
    with pytest.raises(BagError, match='no such bag directory'):
        reindex_bag(tmp_path / 'absent')


KILLS = [('sim', 'process'), ('sim', 'power'), ('robot', 'group'), ('demo', 'process')]


@pytest.mark.parametrize('target,mode', KILLS, ids=[f'{t}-{m}' for t, m in KILLS])
def test_a_hard_kill_leaves_a_bag_both_readers_open_losing_under_a_second(tmp_path, target, mode):
    """SIGKILL at a seeded moment; the sim time reached at the kill comes from /clock (the demo: its clock
    file; the processes are stopped first), the bag's stamps are sim time: at most the last second is missing."""
    from hexapod_sim.bench.kill_bench import ClockWatch
    domain = 156 + KILLS.index((target, mode))
    delay = random.Random(f'{target}-{mode}').uniform(3.0, 8.0)
    env = node_env(domain)
    import os
    os.environ.update(ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST')
    clock = ClockWatch() if target != 'demo' else None
    try:
        with open(tmp_path / 'log', 'w') as log:
            res = kill_one(0, target, mode, delay, tmp_path / 'bag', env, clock, log)
    finally:
        if clock is not None:
            clock.close()
    assert res.project_ok, res.line()
    if mode == 'power':        # the writer was killed too: the bag needed reindex to open in rosbags
        assert res.reindexed and res.rosbags_after_ok, res.line()
    else:                      # the writer process finished the bag
        assert res.rosbags_ok and not res.reindexed, res.line()
    reader = _read_both(tmp_path / 'bag')
    topics = set(reader.topics())
    assert {'/joint_states', '/robot_description', '/tf_static'} <= topics, topics
    assert reader.start_ns < 0.1e9                          # from the start of the sim
    assert res.t_kill_s is not None and res.t_kill_s > 1.0, res.line()     # the demo's from its clock file
    assert res.lost_s <= 1.0, res.line()
    if target != 'demo':
        assert {'/clock', '/imu'} <= topics
    else:
        assert {'/swing_down', '/ground_detection', '/joint_commands'} <= topics
    # stamps are sim time and consistent: every /joint_states stamp within 0.1 s of its log time
    for m in reader.messages(topics=['/joint_states']):
        assert abs(m.msg.header.stamp.sec + m.msg.header.stamp.nanosec * 1e-9 - m.t_ns * 1e-9) < 0.1
