"""Recorder: bag paths, ROS messages as plain data, and a crash loses at most the last second."""
import shutil
import warnings
from pathlib import Path

import pytest

from hexapod_model.contract import stamp_dict
from hexapod_sim.bagio import BagReader, recorder
from hexapod_sim.bagio.recorder import Recorder, resolve_bag_dir, ros_to_plain
from hexapod_sim.bagio.recorder_process import RecorderProcess


def test_bag_paths(monkeypatch, tmp_path):
    monkeypatch.setenv('HEXAPOD_BAGS', str(tmp_path))
    auto = resolve_bag_dir('auto', prefix='demo')
    assert auto.parent == tmp_path and auto.name.startswith('demo_')
    assert resolve_bag_dir('run1') == tmp_path / 'run1'
    assert resolve_bag_dir('/x/y') == Path('/x/y')
    with pytest.raises(ValueError, match='empty'):
        resolve_bag_dir('')
    monkeypatch.delenv('HEXAPOD_BAGS')
    assert recorder.default_bag_root().name == 'bags'


def test_ros_message_to_plain():
    pytest.importorskip('rclpy')
    from sensor_msgs.msg import JointState
    m = JointState(name=['leg1_femur'], position=[0.25])
    m.header.stamp.sec, m.header.stamp.nanosec = 3, 7
    assert ros_to_plain(m) == {'header': {'stamp': {'sec': 3, 'nanosec': 7}, 'frame_id': ''},
                               'name': ['leg1_femur'], 'position': [0.25], 'velocity': [], 'effort': []}


def test_a_crash_loses_at_most_the_last_second(tmp_path):
    bag = tmp_path / 'live'
    rec = Recorder(bag)
    try:
        for k in range(3001):                       # 3 s of simulated time at 1 kHz
            t = k * 0.001
            clock = {'clock': stamp_dict(t)}
            rec.write('/clock', 'rosgraph_msgs/msg/Clock', clock, t)
        crashed = tmp_path / 'crashed'
        shutil.copytree(bag, crashed)               # the files as a crash would leave them
    finally:
        rec.close()
    with warnings.catch_warnings():                 # the reader warns that the bag was cut off
        warnings.simplefilter('ignore')
        msgs = list(BagReader(crashed).messages())
    assert msgs and msgs[-1][2] >= int(2.0e9)       # everything up to the last second survived
    assert len(list(BagReader(bag).messages(topics=['/clock']))) == 3001   # + robot description, /tf_static


def test_fast_cdr_packers_match_the_bag_writers_encoder(tmp_path):
    pytest.importorskip('rclpy')
    import numpy as np
    from rosgraph_msgs.msg import Clock
    from sensor_msgs.msg import JointState

    from hexapod_sim.bagio import BagWriter
    rng = np.random.default_rng(0)
    w = BagWriter(tmp_path / 'enc')
    try:
        for k in range(50):
            n = int(rng.integers(0, 4))
            m = JointState(name=[('x' * int(rng.integers(0, 12))) for _ in range(n)],
                           position=rng.normal(size=n).tolist(),
                           velocity=rng.normal(size=int(rng.integers(0, 3))).tolist(),
                           effort=rng.normal(size=int(rng.integers(0, 3))).tolist())
            m.header.stamp.sec, m.header.stamp.nanosec = int(rng.integers(0, 10**6)), int(rng.integers(0, 10**9))
            m.header.frame_id = 'f' * int(rng.integers(0, 6))
            assert recorder.cdr_joint_state(m) == w.encode('sensor_msgs/msg/JointState', ros_to_plain(m)), k
            c = Clock()
            c.clock.sec, c.clock.nanosec = int(rng.integers(0, 10**6)), int(rng.integers(0, 10**9))
            assert recorder.cdr_clock(c) == w.encode('rosgraph_msgs/msg/Clock', ros_to_plain(c))
    finally:
        w.close()


def test_fast_cdr_packers_for_imu_pose_and_arrays(tmp_path):
    pytest.importorskip('rclpy')
    import numpy as np
    from geometry_msgs.msg import PoseStamped
    from sensor_msgs.msg import Imu
    from std_msgs.msg import Float64MultiArray, MultiArrayDimension

    from hexapod_sim.bagio import BagWriter
    rng = np.random.default_rng(1)
    w = BagWriter(tmp_path / 'enc')
    try:
        for k in range(30):
            imu = Imu()
            imu.header.frame_id = 't' * int(rng.integers(0, 9))
            imu.header.stamp.sec = int(rng.integers(0, 1000))
            imu.orientation.x, imu.orientation.w = rng.normal(size=2)
            imu.linear_acceleration.z = float(rng.normal())
            imu.angular_velocity_covariance = rng.normal(size=9)
            assert recorder.cdr_imu(imu) == w.encode('sensor_msgs/msg/Imu', ros_to_plain(imu)), k
            p = PoseStamped()
            p.header.frame_id = 'w' * int(rng.integers(0, 9))
            p.pose.position.y, p.pose.orientation.z = rng.normal(size=2)
            assert recorder.cdr_pose_stamped(p) == w.encode('geometry_msgs/msg/PoseStamped', ros_to_plain(p)), k
            a = Float64MultiArray(data=rng.normal(size=int(rng.integers(0, 30))).tolist())
            a.layout.dim = [MultiArrayDimension(label='l' * int(rng.integers(0, 7)), size=int(rng.integers(0, 9)),
                                                stride=3) for _ in range(int(rng.integers(0, 3)))]
            a.layout.data_offset = int(rng.integers(0, 5))
            assert recorder.cdr_float64_multi_array(a) == w.encode('std_msgs/msg/Float64MultiArray',
                                                                   ros_to_plain(a)), k
    finally:
        w.close()


def _calls(n_ms: int):
    """The sim node's recording calls for ``n_ms`` of a run, as plain data: (kind, args)."""
    import numpy as np

    from hexapod_model.description import ALL_JOINTS
    rng = np.random.default_rng(3)
    for k in range(n_ms):
        t = k * 0.001
        joint = ALL_JOINTS[k % 18]
        yield 'write', ('joint_states', 'sensor_msgs/msg/JointState',
                        {'header': {'stamp': stamp_dict(t)}, 'name': [joint], 'position': [float(rng.normal())]},
                        t + 0.001)
        yield 'write', ('clock', 'rosgraph_msgs/msg/Clock', {'clock': stamp_dict(t)}, t)
        if k % 10 == 0:
            yield 'tf', (t, ALL_JOINTS, rng.uniform(-0.5, 0.5, 18), ([0.0, 0.0, 0.1], [1.0, 0.0, 0.0, 0.0]))


def _raw(bag):
    """Every message of the bag in the order it was written to the file (not sorted by log time)."""
    from mcap.reader import make_reader
    out = []
    for f in sorted(Path(bag).glob('*.mcap')):
        with open(f, 'rb') as fh:
            for _schema, channel, m in make_reader(fh).iter_messages(log_time_order=False):
                out.append((channel.topic, m.log_time, bytes(m.data)))
    return out


def test_recorder_thread_writes_what_the_recorder_writes_in_line(tmp_path):
    """The sim node's writer thread: the same calls give the same bag, message for message in file
    order, and close() writes everything enqueued before it (a small queue makes the callers wait,
    not drop)."""
    with Recorder(tmp_path / 'inline') as rec:
        for kind, args in _calls(1500):
            if kind == 'write':
                rec.write(*args)
            elif rec.tf_due(args[0]):
                rec.write_tf(*args)
    threaded = recorder.RecorderThread(Recorder(tmp_path / 'threaded'), max_queued=64)
    for kind, args in _calls(1500):
        (threaded.write if kind == 'write' else threaded.write_tf_if_due)(*args)
    threaded.close()
    threaded.close()                                   # idempotent
    want = _raw(tmp_path / 'inline')
    assert threaded.error is None and threaded.close_error is None
    assert threaded.count == len(want) == 1500 * 2 + 2 + 76    # + robot description, /tf_static; /tf at 50 Hz
    got = _raw(tmp_path / 'threaded')
    assert [m[:2] for m in got] == [m[:2] for m in want]        # same topics and times in the same order
    assert got == want
    assert BagReader(tmp_path / 'threaded').complete
    threaded.write('clock', 'rosgraph_msgs/msg/Clock', {'clock': stamp_dict(9.0)}, 9.0)   # after close: ignored
    assert threaded.count == len(want)


def _clocks(rec, offset, n):
    for k in range(n):
        t = offset + k * 0.001
        rec.write('clock', 'rosgraph_msgs/msg/Clock', {'clock': stamp_dict(t)}, t)


def _producer_stamps(bag, offset):
    """The log times of one producer's messages (offset .. offset + 9 s), in file order."""
    return [t for topic, t, _ in _raw(bag) if offset * 1e9 <= t < (offset + 9.0) * 1e9]


def test_recorder_thread_takes_writes_from_several_threads_in_each_ones_order(tmp_path):
    import threading
    rec = recorder.RecorderThread(Recorder(tmp_path / 'many', tf_rate_hz=0), max_queued=16)
    threads = [threading.Thread(target=_clocks, args=(rec, i * 10.0, 2000)) for i in range(3)]
    for th in threads:
        th.start()
    for th in threads:
        th.join()
    rec.close()
    for i in range(3):
        assert _producer_stamps(tmp_path / 'many', i * 10.0) == [int(round((i * 10.0 + k * 0.001) * 1e9))
                                                                 for k in range(2000)]


def test_close_while_threads_write_keeps_what_came_before_and_never_blocks_a_writer(tmp_path):
    """Executor callbacks may still record while the node closes: each writer's messages in the bag
    are exactly those it had handed over before close() (none after, none lost), and no writer
    waits for ever on a queue whose writer thread has ended (a queue of 1 makes that likely)."""
    import threading
    import time
    rec = recorder.RecorderThread(Recorder(tmp_path / 'race', tf_rate_hz=0), max_queued=1)
    stop = threading.Event()
    handed = [[] for _ in range(4)]

    def produce(i):
        k = 0
        while not stop.is_set():
            t = i * 10.0 + k * 0.001
            rec.write('clock', 'rosgraph_msgs/msg/Clock', {'clock': stamp_dict(t)}, t)
            handed[i].append((t, rec._closed))      # closed already when this write returned: maybe dropped
            k += 1
    threads = [threading.Thread(target=produce, args=(i,), daemon=True) for i in range(4)]
    for th in threads:
        th.start()
    time.sleep(0.3)
    rec.close()
    stop.set()
    for th in threads:
        th.join(10.0)
    assert not any(th.is_alive() for th in threads), 'a writer is blocked after close()'
    assert rec.error is None and rec.close_error is None
    for i in range(4):
        got = _producer_stamps(tmp_path / 'race', i * 10.0)
        before = [int(round(t * 1e9)) for t, closed in handed[i] if not closed]
        # every write that returned before close() began is in the bag, in order, and nothing
        # after a dropped one: the bag holds a prefix of what this thread handed over
        assert got[:len(before)] == before, i
        assert got == [int(round(t * 1e9)) for t, _ in handed[i][:len(got)]], i
    assert 4 < rec.count <= sum(len(h) for h in handed)
    assert BagReader(tmp_path / 'race').complete


def test_a_failed_write_stops_the_recording_in_one_report_and_keeps_the_bag(tmp_path):
    errors = []
    rec = recorder.RecorderThread(Recorder(tmp_path / 'bad', tf_rate_hz=0), on_error=errors.append)
    rec.write('clock', 'rosgraph_msgs/msg/Clock', {'clock': stamp_dict(0.0)}, 0.0)
    rec.write('clock', 'std_msgs/msg/String', {'data': 'not a clock'}, 0.001)     # the topic has another type
    rec.write('clock', 'rosgraph_msgs/msg/Clock', {'clock': stamp_dict(0.002)}, 0.002)
    rec.close()
    assert errors == [rec.error]
    assert rec.error == ('clock: topic /clock is recorded as rosgraph_msgs/msg/Clock, '
                         'cannot write std_msgs/msg/String on it'), rec.error
    assert rec.close_error is None
    rec.write('clock', 'rosgraph_msgs/msg/Clock', {'clock': stamp_dict(0.003)}, 0.003)     # closed: dropped
    reader = BagReader(tmp_path / 'bad')
    assert reader.complete and [m.t_ns for m in reader.messages()] == [0]


def test_a_bag_that_cannot_be_closed_is_said_so_once_by_the_caller(tmp_path):
    errors = []
    rec = recorder.RecorderThread(Recorder(tmp_path / 'unclosable', tf_rate_hz=0), on_error=errors.append)
    rec.write('clock', 'rosgraph_msgs/msg/Clock', {'clock': stamp_dict(0.0)}, 0.0)

    def full(*_):
        raise OSError(28, 'No space left on device')
    rec.recorder._writer._mcap.finish = full          # the summary cannot be written
    rec.close()
    assert errors == [] and rec.error is None
    # one line naming the bag, the failure and what the bag kept (the writer ends it at its last flush)
    assert 'unclosable' in rec.close_error and 'No space left on device' in rec.close_error
    assert '\n' not in rec.close_error


def test_one_line_names_the_error_in_one_line():
    assert recorder.one_line(OSError(28, 'No space left on device')) == '[Errno 28] No space left on device'
    assert recorder.one_line(KeyError('name')) == "KeyError: 'name'"
    assert recorder.one_line(RuntimeError('first\nsecond')) == 'RuntimeError: first'
    assert recorder.one_line(ValueError()) == 'ValueError'


def test_recorder_process_writes_what_the_recorder_writes_in_line(tmp_path):
    """The sim node's recording process: the same calls give the same bag as the recorder in line,
    close() writes everything enqueued before it, and the count is the bag's."""
    with Recorder(tmp_path / 'inline') as rec:
        for kind, args in _calls(1500):
            if kind == 'write':
                rec.write(*args)
            elif rec.tf_due(args[0]):
                rec.write_tf(*args)
    child = RecorderProcess(tmp_path / 'child', max_queued=64)
    for kind, args in _calls(1500):
        (child.write if kind == 'write' else child.write_tf_if_due)(*args)
    child.close()
    child.close()                                      # idempotent
    want = _raw(tmp_path / 'inline')
    assert child.error is None and child.close_error is None
    assert child.count == len(want)
    assert _raw(tmp_path / 'child') == want
    assert BagReader(tmp_path / 'child').complete


def test_recorder_process_reports_a_failed_write_once_and_refuses_a_bad_place_in_one_line(tmp_path):
    errors = []
    rec = RecorderProcess(tmp_path / 'bad', tf_rate_hz=0, on_error=errors.append)
    rec.write('clock', 'rosgraph_msgs/msg/Clock', {'clock': stamp_dict(0.0)}, 0.0)
    rec.write('clock', 'std_msgs/msg/String', {'data': 'not a clock'}, 0.001)     # the topic has another type
    rec.write('clock', 'rosgraph_msgs/msg/Clock', {'clock': stamp_dict(0.002)}, 0.002)
    rec.close()
    assert errors == [rec.error] == ['clock: topic /clock is recorded as rosgraph_msgs/msg/Clock, '
                                     'cannot write std_msgs/msg/String on it']
    assert rec.count == 1 and [m.t_ns for m in BagReader(tmp_path / 'bad').messages()] == [0]
    (tmp_path / 'full').mkdir()
    (tmp_path / 'full' / 'x').write_text('x')
    from hexapod_sim.bagio import BagError
    with pytest.raises(BagError, match='already exists and is not an empty directory') as exc:
        RecorderProcess(tmp_path / 'full')
    assert '\n' not in str(exc.value)


@pytest.mark.parametrize('kind', ['process', 'thread'])
def test_a_queue_lock_left_taken_by_an_interrupted_writer_does_not_stop_the_close(tmp_path, kind):
    """Ctrl-C's KeyboardInterrupt can arrive in a writer after it took the queue's lock and before its
    ``with`` block began: the lock stays taken (the demo hung at exit so). close() takes it over after
    END_QUEUE_WAIT_S, writes what was queued before and closes the bag."""
    import threading
    rec = (RecorderProcess(tmp_path / 'bag', tf_rate_hz=0) if kind == 'process'
           else recorder.RecorderThread(Recorder(tmp_path / 'bag', tf_rate_hz=0)))
    for kind_, args in _calls(200):
        if kind_ == 'write':
            rec.write(*args)
    rec._not_full.acquire()                            # what the interrupted writer left
    closer = threading.Thread(target=rec.close, daemon=True)
    closer.start()
    closer.join(timeout=30)
    assert not closer.is_alive(), 'close() waits for a lock nobody will give back'
    assert rec.error is None and rec.count > 0
    assert BagReader(tmp_path / 'bag').complete


def test_recorder_process_holds_its_caller_within_max_lag_of_what_the_child_has_written(tmp_path):
    """A hard kill of the caller loses only what the child has not written: however far behind the child
    falls (here stopped), write() waits once its message is max_lag_s of log time ahead of the last one
    written; a jump in log time waits only for the messages before it. The bag holds every message."""
    import os
    import signal
    import threading
    rec = RecorderProcess(tmp_path / 'bag', tf_rate_hz=0, max_lag_s=0.3)
    reached = []

    def walk(times):
        for t in times:
            rec.write('clock', 'rosgraph_msgs/msg/Clock', {'clock': stamp_dict(t)}, t)
            reached.append(t)

    os.kill(rec._proc.pid, signal.SIGSTOP)
    try:
        writer = threading.Thread(target=walk, args=([i * 0.01 for i in range(100)] + [50.0, 50.01],), daemon=True)
        writer.start()
        writer.join(timeout=3.0)
        assert writer.is_alive() and 0 < len(reached) <= 31 and reached[-1] <= 0.3 + 1e-9, reached[-3:]
    finally:
        os.kill(rec._proc.pid, signal.SIGCONT)
    writer.join(timeout=60)
    assert not writer.is_alive() and len(reached) == 102
    rec.close()
    assert rec.error is None and rec.count == 102
    assert [m.t_ns for m in BagReader(tmp_path / 'bag').messages()][-2:] == [50_000_000_000, 50_010_000_000]
    with pytest.raises(ValueError, match='max_lag_s must be > 0'):
        RecorderProcess(tmp_path / 'never', max_lag_s=0)
