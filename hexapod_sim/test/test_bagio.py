"""Bag I/O: rosbag2 layout, round trips, writer input, crash safety."""
import json
import os
import random
import shutil
import signal
import subprocess
import sys
import textwrap
import warnings
from pathlib import Path

import numpy as np
import pytest
import yaml
from bag_samples import JS, REPO, T0, as_plain, assert_subset, sample_messages, write_bag

from hexapod_model import contract
from hexapod_sim import bagio
from hexapod_sim.bagio import BagError, BagReader, BagWarning, BagWriter, MessageEncodeError

# ------------------------------------------------------------------------------ layout ----------

def test_round_trip_layout_and_metadata(tmp_path):
    msgs = sample_messages()
    bag = write_bag(tmp_path / 'run1', msgs)
    assert sorted(p.name for p in bag.iterdir()) == ['metadata.yaml', 'run1_0.mcap']
    info = yaml.safe_load((bag / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    assert info['version'] == 9 and info['storage_identifier'] == 'mcap'
    assert info['relative_file_paths'] == ['run1_0.mcap']
    assert info['message_count'] == len(msgs)
    assert info['starting_time']['nanoseconds_since_epoch'] == min(m[3] for m in msgs)
    assert info['duration']['nanoseconds'] == max(m[3] for m in msgs) - min(m[3] for m in msgs)
    counts = {e['topic_metadata']['name']: e['message_count'] for e in info['topics_with_message_count']}
    assert counts == {t: sum(1 for m in msgs if m[0] == t) for t in {m[0] for m in msgs}}
    for e in info['topics_with_message_count']:
        tm = e['topic_metadata']
        assert tm['serialization_format'] == 'cdr'
        assert isinstance(tm['offered_qos_profiles'], list) and tm['offered_qos_profiles'][0]['reliability'] == 'reliable'
        assert tm['type_description_hash'].startswith('RIHS01_')

    reader = BagReader(bag)
    assert reader.complete and reader.warnings == []
    assert reader.topics() == {m[0]: m[1] for m in msgs}
    got = list(reader.messages())
    expected = sorted(msgs, key=lambda m: m[3])
    assert [(g.topic, g.msg_type, g.t_ns) for g in got] == [(m[0], m[1], m[3]) for m in expected]
    for g, m in zip(got, expected):
        assert_subset(m[2], as_plain(g.msg))
    # time window and topic filter
    sel = list(reader.messages(topics=[contract.IMU], start_ns=T0 + 1, end_ns=T0 + 200_000_000))
    imu = contract.bag_topic(contract.IMU)
    assert [g.t_ns for g in sel] == [m[3] for m in expected if m[0] == imu and T0 + 1 <= m[3] < T0 + 200_000_000]
    assert list(reader.messages(topics=['/not_recorded'])) == []
    # single .mcap path reads the same
    assert [(g.topic, g.t_ns) for g in BagReader(bag / 'run1_0.mcap').messages()] == [(g.topic, g.t_ns) for g in got]


def test_message_definition_is_rosbag2_concatenation():
    # Expected by hand: own text, then dependencies depth first in sorted order, each once, each
    # after "\n" + 80 '=' + "\nMSG: <name as written in the .msg>\n" (rosbag2 LocalMessageDefinitionSource).
    text = bagio.message_definition('hexapod_msgs/msg/ServoDiagnostics')
    parts = text.split('\n' + '=' * 80 + '\n')
    heads = [p.splitlines()[0] for p in parts[1:]]
    assert heads == ['MSG: hexapod_msgs/ServoStatus', 'MSG: std_msgs/Header', 'MSG: builtin_interfaces/Time']
    assert parts[0] == (REPO / 'hexapod_msgs' / 'msg' / 'ServoDiagnostics.msg').read_text()
    assert parts[1] == 'MSG: hexapod_msgs/ServoStatus\n' + (REPO / 'hexapod_msgs' / 'msg' / 'ServoStatus.msg').read_text()
    assert 'int32 sec' in parts[3] and 'uint32 nanosec' in parts[3]
    # each dependency appears once even when reachable twice (Imu: Header, Quaternion, Vector3 x2)
    imu = bagio.message_definition('sensor_msgs/Imu')
    assert imu.count('MSG: geometry_msgs/Vector3') == 1 and imu.count('MSG: builtin_interfaces/Time') == 1
    with pytest.raises(BagError, match='no message definition for acme_msgs/msg/Widget'):
        bagio.message_definition('acme_msgs/msg/Widget')
    with pytest.raises(BagError, match='invalid message type'):
        bagio.normalize_type_name('JointState')


def test_embedded_definitions_match_installed_interfaces():
    embedded = json.loads(bagio._EMBEDDED_PATH.read_text())['types']
    checked = 0
    for typ, entry in embedded.items():
        pkg, _, name = typ.split('/')
        for prefix in filter(None, os.environ.get('AMENT_PREFIX_PATH', '').split(os.pathsep)):
            f = Path(prefix) / 'share' / pkg / 'msg' / f'{name}.msg'
            if f.is_file():
                assert f.read_text() == entry['msg'], typ
                hashes = json.loads(f.with_suffix('.json').read_text())['type_hashes']
                assert entry['rihs01'] == next(h['hash_string'] for h in hashes if h['type_name'] == typ)
                checked += 1
                break
    if checked == 0:
        pytest.skip('no ROS interface packages on AMENT_PREFIX_PATH to compare the embedded copies with')
    # tf2_msgs has no wheel: its upstream text is embedded and its hash is recomputed from that text;
    # where ./hexapod setup built the workspace's tf2_msgs (or ROS's is installed) it is compared too
    tf2 = any((Path(p) / 'share' / 'tf2_msgs' / 'msg' / 'TFMessage.msg').is_file()
              for p in filter(None, os.environ.get('AMENT_PREFIX_PATH', '').split(os.pathsep)))
    assert checked == len(embedded) - (0 if tf2 else 1)
    assert embedded['tf2_msgs/msg/TFMessage']['msg'] == 'geometry_msgs/TransformStamped[] transforms\n'


def test_embedded_tf2_msgs_hash_is_rosidls_hash_of_its_text(tmp_path):
    """The RIHS01 hash of the embedded tf2_msgs/msg/TFMessage, as rosidl computes it at build time."""
    adapter = pytest.importorskip('rosidl_adapter.msg')
    type_description = pytest.importorskip('rosidl_generator_type_description')
    includes = []
    for pkg in ('geometry_msgs', 'std_msgs', 'builtin_interfaces'):
        share = next((Path(p) / 'share' / pkg for p in os.environ.get('AMENT_PREFIX_PATH', '').split(os.pathsep)
                      if p and (Path(p) / 'share' / pkg / 'msg').is_dir()), None)
        if share is None:
            pytest.skip(f'{pkg} is not installed (its type descriptions are needed for the hash)')
        includes.append(f'{pkg}:{share}')
    entry = json.loads(bagio._EMBEDDED_PATH.read_text())['types']['tf2_msgs/msg/TFMessage']
    (tmp_path / 'tf2_msgs' / 'msg').mkdir(parents=True)
    (tmp_path / 'tf2_msgs' / 'msg' / 'TFMessage.msg').write_text(entry['msg'])
    adapter.convert_msg_to_idl(tmp_path / 'tf2_msgs', 'tf2_msgs', Path('msg/TFMessage.msg'), tmp_path / 'idl')
    args = tmp_path / 'args.json'
    args.write_text(json.dumps({'package_name': 'tf2_msgs', 'output_dir': str(tmp_path / 'out'),
                                'idl_tuples': [f'{tmp_path / "idl"}:TFMessage.idl'], 'include_paths': includes}))
    (out,) = type_description.generate_type_hash(str(args))
    hashes = json.loads(Path(out).read_text())['type_hashes']
    assert entry['rihs01'] == next(h['hash_string'] for h in hashes if h['type_name'] == 'tf2_msgs/msg/TFMessage')


def test_definitions_work_without_ros(tmp_path):
    """With no AMENT_PREFIX_PATH and no rclpy, the embedded/source definitions still write and read."""
    script = textwrap.dedent(f'''
        import sys, builtins
        real_import = builtins.__import__
        def no_ros(name, *a, **k):
            if name.split('.')[0] in ('rclpy', 'sensor_msgs', 'std_msgs', 'ament_index_python'):
                raise ImportError(name)
            return real_import(name, *a, **k)
        builtins.__import__ = no_ros
        from hexapod_sim.bagio import BagWriter, BagReader
        with BagWriter({str(tmp_path / 'noros')!r}) as w:
            w.write('/joint_states', 'sensor_msgs/msg/JointState', {{'name': ['a'], 'position': [1.5]}}, 5)
            w.write('/read_schedule', 'hexapod_msgs/msg/ReadSchedule', {{'joint_names': ['leg1_femur']}}, 6)
            w.write('/clock', 'rosgraph_msgs/msg/Clock', {{'clock': {{'sec': 3, 'nanosec': 4}}}}, 7)
        got = [(m.topic, m.t_ns) for m in BagReader({str(tmp_path / 'noros')!r}).messages()]
        assert got == [('/joint_states', 5), ('/read_schedule', 6), ('/clock', 7)], got
        print('ok')
    ''')
    env = {k: v for k, v in os.environ.items() if k != 'AMENT_PREFIX_PATH'}
    res = subprocess.run([sys.executable, '-c', script], env=env, capture_output=True, text=True, timeout=120)
    assert res.returncode == 0 and res.stdout.strip() == 'ok', res.stderr


# ------------------------------------------------------------------------------ writer input ----

def test_ros_message_and_dict_encode_identically(tmp_path):
    """Our CDR (from a dict, or from a ROS object by field introspection) deserializes in rclpy to
    the same message. (Bytes are not compared: Fast-CDR leaves alignment padding uninitialized.)"""
    rclpy_ser = pytest.importorskip('rclpy.serialization')
    from sensor_msgs.msg import Imu, JointState
    js = JointState()
    js.header.stamp.sec, js.header.stamp.nanosec = 12, 345
    js.name, js.position, js.velocity = ['leg1_femur', 'leg1_tibia'], [0.25, -1.5], [0.0, 2.0]
    imu = Imu()
    imu.orientation.w = 1.0
    imu.orientation_covariance = np.arange(9, dtype=float)   # numpy fixed array
    with BagWriter(tmp_path / 'b') as w:
        as_dict = w.encode(JS, {'header': {'stamp': {'sec': 12, 'nanosec': 345}}, 'name': ['leg1_femur', 'leg1_tibia'],
                                'position': [0.25, -1.5], 'velocity': [0, 2]})
        assert rclpy_ser.deserialize_message(as_dict, JointState) == js
        assert w.encode(JS, js) == as_dict       # a ROS object encodes exactly like the same dict
        assert rclpy_ser.deserialize_message(w.encode('sensor_msgs/msg/Imu', imu), Imu) == imu
        assert rclpy_ser.deserialize_message(w.encode(JS, js), JointState) == js
        w.write('/imu', 'sensor_msgs/msg/Imu', imu, 1)
        with pytest.raises(MessageEncodeError, match='got a sensor_msgs/msg/JointState message'):
            w.write('/imu', 'sensor_msgs/msg/Imu', js, 2)
    (m,) = BagReader(tmp_path / 'b').messages()
    assert list(m.msg.orientation_covariance) == list(range(9))


@pytest.mark.parametrize('msg, match', [
    ({'positon': [1.0]}, r"unknown field\(s\) \['positon'\]"),
    ({'position': ['x']}, r'JointState.position\[0\]: expected float64'),
    ({'header': {'stamp': {'sec': 2**31}}}, r'header.stamp.sec: 2147483648 out of range for int32'),
    ({'name': 'leg1_femur'}, r'name: expected a sequence'),
    ({'header': {'frame_id': 3}}, r'header.frame_id: expected string'),
])
def test_bad_messages_are_named(tmp_path, msg, match):
    with BagWriter(tmp_path / 'b') as w:
        with pytest.raises(MessageEncodeError, match=match):
            w.write('/joint_states', JS, msg, 1)


def test_bad_writer_arguments(tmp_path):
    with BagWriter(tmp_path / 'b') as w:
        with pytest.raises(BagError, match='invalid topic name'):
            w.write('/', JS, {}, 1)
        with pytest.raises(BagError, match='invalid topic name'):
            w.write(None, JS, {}, 1)
        with pytest.raises(BagError, match='t_ns must be a non-negative integer'):
            w.write('/joint_states', JS, {}, -1)
        with pytest.raises(BagError, match='t_ns must be a non-negative integer'):
            w.write('/joint_states', JS, {}, 1.5)
        w.write('/joint_states', JS, {}, 1)
        with pytest.raises(BagError, match='recorded as sensor_msgs/msg/JointState'):
            w.write('/joint_states', 'sensor_msgs/msg/Imu', {}, 2)
        with pytest.raises(BagError, match='no message definition'):
            w.write('/widget', 'acme_msgs/msg/Widget', {}, 3)
        with pytest.raises(MessageEncodeError, match='CDR encapsulation header'):
            w.write('/joint_states', JS, b'garbage', 4)
    with pytest.raises(BagError, match='writer is closed'):
        w.write('/joint_states', JS, {}, 5)
    with pytest.raises(BagError, match='not an empty directory'):
        BagWriter(tmp_path / 'b')
    with pytest.raises(BagError, match='flush_period_s must be a positive'):
        BagWriter(tmp_path / 'c', flush_period_s=0)
    with pytest.raises(BagError, match="compression must be"):
        BagWriter(tmp_path / 'd', compression='gzip')


def test_out_of_order_writes_are_read_in_time_order(tmp_path):
    rng = random.Random(3)
    times = [T0 + rng.randrange(0, 10**9) for _ in range(300)]
    with BagWriter(tmp_path / 'b', chunk_size=800) as w:
        for i, t in enumerate(times):
            w.write('/joint_states', JS, {'position': [float(i)]}, t)
    got = [m.t_ns for m in BagReader(tmp_path / 'b').messages()]
    assert got == sorted(times)


# ------------------------------------------------------------------------------ crash safety ----

def test_killed_recorder_leaves_a_readable_bag(tmp_path):
    """SIGKILL mid-recording: metadata.yaml and everything older than one flush period survive."""
    bag = tmp_path / 'crash'
    script = textwrap.dedent(f'''
        import os, signal
        from hexapod_sim.bagio import BagWriter
        w = BagWriter({str(bag)!r}, flush_period_s=1.0)
        for i in range(3500):              # 3.5 s of message time at 1 kHz
            w.write('/joint_states', 'sensor_msgs/msg/JointState', {{'position': [float(i)]}}, {T0} + i * 1_000_000)
        os.kill(os.getpid(), signal.SIGKILL)
    ''')
    res = subprocess.run([sys.executable, '-c', script], capture_output=True, text=True, timeout=120)
    assert res.returncode == -signal.SIGKILL, res.stderr
    info = yaml.safe_load((bag / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    assert info['version'] == 9 and info['relative_file_paths'] == ['crash_0.mcap']
    assert info['message_count'] >= 3000      # flushed at 1, 2 and 3 s of message time
    with pytest.warns(BagWarning, match='without the MCAP summary/footer'):
        reader = BagReader(bag)
    got = [int(m.msg.position[0]) for m in reader.messages()]
    assert got == list(range(len(got))) and len(got) >= 3000
    assert len(got) >= info['message_count']
    # other tools need the footer: recover_bag rewrites what is readable into a closed bag
    pytest.importorskip('rosbags')
    from rosbags.rosbag2 import Reader
    with pytest.warns(BagWarning, match='without the MCAP summary/footer'):
        assert bagio.recover_bag(bag, tmp_path / 'fixed') == len(got)
    with Reader(tmp_path / 'fixed') as r:
        assert r.message_count == len(got)
        assert r.connections[0].digest == bagio.type_hash(JS)


def test_wall_clock_flush_when_idle(tmp_path):
    """Messages written then nothing more: the background flush puts them on disk within the period."""
    import time
    w = BagWriter(tmp_path / 'idle', flush_period_s=0.2)
    try:
        w.write('/joint_states', JS, {'position': [1.0]}, T0)
        w.write('/joint_states', JS, {'position': [2.0]}, T0 + 1000)
        deadline = time.monotonic() + 10.0
        copy = tmp_path / 'copy'
        while True:                 # poll the on-disk state, as a crash would leave it
            shutil.rmtree(copy, ignore_errors=True)
            shutil.copytree(tmp_path / 'idle', copy)
            try:
                with warnings.catch_warnings():
                    warnings.simplefilter('ignore', BagWarning)
                    n = BagReader(copy).message_count
            except BagError:
                n = 0
            if n == 2 or time.monotonic() > deadline:
                break
            time.sleep(0.05)
        assert n == 2, 'pending messages never reached the disk without a further write or close'
        # metadata.yaml is rewritten right after the data flush (the copy may have caught it just before)
        while True:
            meta = yaml.safe_load((tmp_path / 'idle' / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
            if meta['message_count'] == 2 or time.monotonic() > deadline:
                break
            time.sleep(0.02)
        assert meta['message_count'] == 2
    finally:
        w.close()
