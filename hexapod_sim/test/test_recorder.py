"""Recorder: bag paths, ROS messages as plain data, and a crash loses at most the last second."""
import shutil
import warnings
from pathlib import Path

import pytest

from hexapod_sim.bagio import BagReader
from hexapod_model.contract import stamp_dict
from hexapod_sim import recorder
from hexapod_sim.recorder import Recorder, resolve_bag_dir, ros_to_plain


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
