"""Bag I/O: rosbag2 layout, round trips, crash safety, truncation, garbage, cross-reader checks."""
import base64
import dataclasses
import io
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
from mcap.exceptions import EndOfFile
from mcap.reader import make_reader
from mcap.records import Message
from mcap.stream_reader import StreamReader

from hexapod_model import contract
from hexapod_sim import bagio
from hexapod_sim.bagio import BagError, BagReader, BagWarning, BagWriter, MessageEncodeError

T0 = 1_700_000_000_000_000_000
JS = 'sensor_msgs/msg/JointState'
REPO = Path(__file__).resolve().parents[2]
NODE_READER = REPO / 'tools' / 'mcap-node' / 'read.mjs'


stamp = contract.stamp_dict_ns


def joint_state(t_ns, names, pos):
    return {'header': {'stamp': stamp(t_ns), 'frame_id': ''}, 'name': list(names), 'position': list(pos)}


def sample_messages():
    """(topic as the bag stores it, type, dict, t_ns) covering nested arrays, fixed arrays,
    constants-bearing types."""
    out = []
    for i in range(40):
        t = T0 + i * 7_000_000
        out.append((contract.JOINT_COMMANDS, JS, joint_state(t, ['leg1_coxa', 'leg1_femur'], [0.1 * i, -0.2 * i]), t))
        out.append((contract.JOINT_STATES, JS, {**joint_state(t + 1000, ['leg1_femur'], [0.1 * i - 0.01]),
                                                 'velocity': [0.5], 'effort': []}, t + 1000))
        if i % 10 == 0:
            out.append((contract.IMU, 'sensor_msgs/msg/Imu', {
                'header': {'stamp': stamp(t), 'frame_id': 'base'},
                'orientation': {'x': 0.0, 'y': 0.0, 'z': 0.0, 'w': 1.0},
                'orientation_covariance': [float(k) for k in range(9)],
                'linear_acceleration': {'x': 0.1, 'y': 0.2, 'z': 9.81}}, t + 2000))
            out.append((contract.SERVO_DIAGNOSTICS, 'hexapod_msgs/msg/ServoDiagnostics', {
                'header': {'stamp': stamp(t), 'frame_id': ''},
                'servos': [{'joint_name': 'leg2_tibia', 'id': 9, 'temperature_c': 41.5, 'voltage_v': 11.9,
                            'load_fraction': -0.25, 'error_bits': 32, 'responding': True,
                            'torque_enabled': False, 'message': 'overload'}]}, t + 3000))
            out.append((contract.SIM_TRUTH_CONTACTS, 'std_msgs/msg/Float64MultiArray', {
                'layout': {'dim': [{'label': 'leg', 'size': 6, 'stride': 6}], 'data_offset': 0},
                'data': [1.0, 0.0, 1.0, 0.0, 1.0, 0.0]}, t + 4000))
    return [(contract.bag_topic(topic), *rest) for topic, *rest in out]


def write_bag(path, msgs, **kw):
    with BagWriter(path, **kw) as w:
        for topic, typ, msg, t in msgs:
            w.write(topic, typ, msg, t)
    return path


def as_plain(obj):
    """Decoded message -> nested dict/list of Python values for comparisons."""
    if dataclasses.is_dataclass(obj):       # rosbags messages
        return {f.name: as_plain(getattr(obj, f.name)) for f in dataclasses.fields(obj)}
    if hasattr(obj, '__slots__') and not isinstance(obj, (str, bytes)):
        return {k: as_plain(getattr(obj, k)) for k in obj.__slots__}
    if isinstance(obj, (list, tuple)):
        return [as_plain(x) for x in obj]
    if isinstance(obj, np.ndarray):
        return [as_plain(x) for x in obj.tolist()]
    if isinstance(obj, (bytes, bytearray)):
        return list(obj)
    if isinstance(obj, np.generic):
        return obj.item()
    return obj


def assert_subset(expected, actual, path='msg'):
    """Every field given in ``expected`` has that value in ``actual`` (absent fields = defaults)."""
    if isinstance(expected, dict):
        for k, v in expected.items():
            assert_subset(v, actual[k], f'{path}.{k}')
    elif isinstance(expected, list):
        assert len(expected) == len(actual), path
        for i, (e, a) in enumerate(zip(expected, actual)):
            assert_subset(e, a, f'{path}[{i}]')
    elif isinstance(expected, float):
        assert actual == pytest.approx(expected, rel=1e-6), path
    else:
        assert expected == actual, path


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


# ------------------------------------------------------------------------------ damaged input ---

def chunk_ends_and_counts(mcap_path):
    """(end offset, message count) per chunk, from the file's own chunk index (mcap library)."""
    out = []
    with open(mcap_path, 'rb') as f:
        summary = make_reader(f).get_summary()
        for ci in summary.chunk_indexes:
            f.seek(ci.chunk_start_offset)
            data = f.read(ci.chunk_length)
            n = 0
            try:
                for r in StreamReader(io.BytesIO(data), skip_magic=True).records:
                    n += isinstance(r, Message)
            except EndOfFile:
                pass
            out.append((ci.chunk_start_offset + ci.chunk_length, n))
    return out


def test_truncated_at_arbitrary_bytes(tmp_path):
    msgs = [(contract.JOINT_STATES, JS, joint_state(T0 + i * 10**6, ['leg1_femur'], [float(i)]), T0 + i * 10**6)
            for i in range(400)]
    bag = write_bag(tmp_path / 'full', msgs, chunk_size=1500)
    mcap = bag / 'full_0.mcap'
    size = mcap.stat().st_size
    chunks = chunk_ends_and_counts(mcap)
    assert len(chunks) > 10
    rng = random.Random(7)
    cuts = sorted({0, 3, 8, 20, chunks[0][0] - 1, chunks[0][0], chunks[3][0] + 5, size - 1}
                  | {rng.randrange(9, size) for _ in range(12)})
    for cut in cuts:
        d = tmp_path / f'cut{cut}'
        d.mkdir()
        shutil.copy(bag / 'metadata.yaml', d / 'metadata.yaml')
        (d / 'full_0.mcap').write_bytes(mcap.read_bytes()[:cut])
        expected = sum(n for end, n in chunks if end <= cut)
        if expected == 0:
            with pytest.raises(BagError, match='no readable messages|empty|truncated|nothing is readable'):
                BagReader(d)
            continue
        with pytest.warns(BagWarning) as rec:
            reader = BagReader(d)
        text = ' '.join(str(w.message) for w in rec)
        assert f'{expected} message(s)' in text and 'readable' in text, (cut, text)
        got = [int(m.msg.position[0]) for m in reader.messages()]
        assert got == list(range(expected)), cut


def test_corrupt_chunk_is_skipped_with_warning(tmp_path):
    msgs = [(contract.JOINT_STATES, JS, {'position': [float(i)]}, T0 + i) for i in range(200)]
    bag = write_bag(tmp_path / 'b', msgs, chunk_size=1000, compression='none')
    mcap = bag / 'b_0.mcap'
    chunks = chunk_ends_and_counts(mcap)
    data = bytearray(mcap.read_bytes())
    end2, n2 = chunks[2]
    data[end2 - 20] ^= 0xFF                         # flip a byte inside chunk 2's payload (CRC breaks)
    mcap.write_bytes(bytes(data))
    with pytest.warns(BagWarning, match='corrupt chunk'):
        reader = BagReader(bag)
    got = [int(m.msg.position[0]) for m in reader.messages()]
    lost_from = sum(n for _, n in chunks[:2])
    assert got == list(range(lost_from)) + list(range(lost_from + n2, 200))


@pytest.mark.parametrize('content, match', [
    (b'', 'file is empty'),
    (os.urandom(4096), 'not an MCAP file'),
    (b'rosbag2_bagfile_information: this is a text file\n' * 20, 'not an MCAP file'),
    (b'\x89MC', 'truncated to 3 bytes'),
])
def test_garbage_files(tmp_path, content, match):
    f = tmp_path / 'x.mcap'
    f.write_bytes(content)
    with pytest.raises(BagError, match=match):
        BagReader(f)


def test_garbage_paths_and_directories(tmp_path):
    with pytest.raises(BagError, match='no such file or directory'):
        BagReader(tmp_path / 'missing')
    (tmp_path / 'empty').mkdir()
    with pytest.raises(BagError, match='not a rosbag2 directory'):
        BagReader(tmp_path / 'empty')
    (tmp_path / 'badmeta').mkdir()
    (tmp_path / 'badmeta' / 'metadata.yaml').write_text(': : not yaml [')
    with pytest.raises(BagError, match='not a valid rosbag2 metadata file'):
        BagReader(tmp_path / 'badmeta')
    bag = write_bag(tmp_path / 'gone', [(contract.JOINT_STATES, JS, {}, 1)])
    (bag / 'gone_0.mcap').unlink()
    with pytest.raises(BagError, match=r"lists file\(s\) that do not exist: \['gone_0.mcap'\]"):
        BagReader(bag)
    with BagWriter(tmp_path / 'nomsgs'):
        pass
    with pytest.raises(BagError, match='no readable messages'):
        BagReader(tmp_path / 'nomsgs')


def test_unknown_type_is_skipped_with_one_warning(tmp_path):
    """A topic with no schema and a type unknown here: one warning, other topics read, raw still available."""
    from mcap.writer import Writer
    path = tmp_path / 'foreign.mcap'
    with open(path, 'wb') as f:
        w = Writer(f)
        w.start(profile='ros2', library='test')
        sid = w.register_schema('sensor_msgs/msg/JointState', 'ros2msg', bagio.message_definition(JS).encode())
        known = w.register_channel('/joint_states', 'cdr', sid)
        unknown = w.register_channel('/widget', 'cdr', 0)          # schema id 0 = no schema
        for i in range(5):
            w.add_message(known, T0 + i, _ser_only().encode(JS, {'position': [float(i)]}), T0 + i)
            w.add_message(unknown, T0 + i, b'\x00\x01\x00\x00\x07', T0 + i)
        w.finish()
    with pytest.warns(BagWarning) as rec:
        reader = BagReader(path)
    msgs = [str(r.message) for r in rec if '/widget' in str(r.message)]
    assert len(msgs) == 1 and 'cannot be decoded' in msgs[0] and 'no schema' in msgs[0]
    got = list(reader.messages())
    assert [m.topic for m in got] == ['/joint_states'] * 5
    with warnings_none():
        assert sum(m.topic == '/widget' for m in reader.messages(raw=True)) == 5


def _ser_only():
    """A BagWriter-like object whose encode() needs no open bag (for hand-made MCAP files)."""
    obj = object.__new__(BagWriter)
    obj._serialize_ros = None
    return obj


class warnings_none:
    def __enter__(self):
        self._cm = warnings.catch_warnings()
        self._cm.__enter__()
        warnings.simplefilter('error', BagWarning)

    def __exit__(self, *exc):
        return self._cm.__exit__(*exc)


def test_custom_definition_topic(tmp_path):
    definition = 'float64 level\nstring label\n'
    with BagWriter(tmp_path / 'b') as w:
        w.add_topic('/widget', 'acme_msgs/msg/Widget', definition=definition)
        w.write('/widget', 'acme_msgs/msg/Widget', {'level': 2.5, 'label': 'w'}, 10)
    (m,) = BagReader(tmp_path / 'b').messages()
    assert (m.msg_type, m.msg.level, m.msg.label) == ('acme_msgs/msg/Widget', 2.5, 'w')


# ------------------------------------------------------------------------------ joint series ----

def test_joint_series(tmp_path):
    with BagWriter(tmp_path / 'b') as w:
        for k in range(5):
            t = T0 + k * 4_000_000
            w.write(contract.JOINT_COMMANDS, JS, joint_state(t, ['leg1_coxa', 'leg1_femur'], [0.1 * k, 0.2 * k]), t)
            # one read per message, stamped at the sample time (earlier than the record time)
            w.write(contract.JOINT_STATES, JS, joint_state(t + 1_000_000, ['leg1_femur'], [0.2 * k - 0.05]), t + 1_500_000)
    js = bagio.joint_series(BagReader(tmp_path / 'b'))
    base = T0 / 1e9
    femur_cmd = js[contract.JOINT_COMMANDS]['leg1_femur']
    assert femur_cmd.shape == (5, 2)
    np.testing.assert_allclose(femur_cmd[:, 0] - base, [0.0, 0.004, 0.008, 0.012, 0.016], atol=1e-6)
    np.testing.assert_allclose(femur_cmd[:, 1], [0.0, 0.2, 0.4, 0.6, 0.8])
    meas = js[contract.JOINT_STATES]
    assert list(meas) == ['leg1_femur']
    np.testing.assert_allclose(meas['leg1_femur'][:, 0] - base, [0.001, 0.005, 0.009, 0.013, 0.017], atol=1e-6)
    with BagWriter(tmp_path / 'bad') as w:
        w.write(contract.JOINT_STATES, JS, joint_state(T0, ['a', 'b'], [1.0]), T0)
    with pytest.raises(BagError, match='names 2 joint'):
        bagio.joint_series(BagReader(tmp_path / 'bad'))


def test_relative_contract_names_and_old_absolute_bags_are_one_topic(tmp_path):
    """Contract names are relative (the stack runs under a namespace); a bag stores '/joint_states'
    either way, and readers find bags recorded with the absolute names of before."""
    assert contract.JOINT_STATES == 'joint_states' and contract.bag_topic(contract.JOINT_STATES) == '/joint_states'
    with BagWriter(tmp_path / 'new') as w:
        w.write(contract.JOINT_STATES, JS, joint_state(T0, ['leg1_femur'], [0.5]), T0)
    with BagWriter(tmp_path / 'old') as w:
        w.write('/joint_states', JS, joint_state(T0, ['leg1_femur'], [0.5]), T0)
    for name in ('new', 'old'):
        r = BagReader(tmp_path / name)
        assert list(r.topics()) == ['/joint_states']
        assert r.resolve('joint_states') == r.resolve('/joint_states') == '/joint_states'
        assert [m[0] for m in r.messages(topics=[contract.JOINT_STATES])] == ['/joint_states']
        assert [m[0] for m in r.messages(topics=['/joint_states'])] == ['/joint_states']
        assert bagio.joint_series(r)[contract.JOINT_STATES]['leg1_femur'][0, 1] == 0.5
        assert r.resolve(contract.JOINT_COMMANDS) is None


# ------------------------------------------------------------------------------ cross readers ---

def test_rosbags_reads_the_same(tmp_path):
    rosbags = pytest.importorskip('rosbags')
    from rosbags.rosbag2 import Reader
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore
    msgs = sample_messages()
    bag = write_bag(tmp_path / 'x', msgs)
    ours = [(m.topic, m.t_ns, as_plain(m.msg)) for m in BagReader(bag).messages()]
    store = get_typestore(Stores.EMPTY)
    theirs = []
    with Reader(bag) as reader:
        for conn in reader.connections:
            store.register(get_types_from_msg(conn.msgdef.data, conn.msgtype))
        assert {c.topic: c.msgtype for c in reader.connections} == {m[0]: m[1] for m in msgs}
        assert all(c.digest.startswith('RIHS01_') for c in reader.connections)
        for conn, t, raw in reader.messages():
            theirs.append((conn.topic, t, as_plain(store.deserialize_cdr(raw, conn.msgtype))))
    assert rosbags.__name__ and len(theirs) == len(ours)
    for (t1, ts1, m1), (t2, ts2, m2) in zip(ours, theirs):
        assert (t1, ts1) == (t2, ts2)
        assert_subset(m1, m2, t1)


def test_mcap_core_node_reads_the_same(tmp_path):
    if shutil.which('node') is None:
        pytest.skip('node is not installed: the @mcap/core cross-check needs Node.js')
    if not (REPO / 'tools' / 'mcap-node' / 'node_modules' / '@mcap' / 'core').is_dir():
        pytest.skip('tools/mcap-node/node_modules/@mcap/core missing (./hexapod setup runs npm ci)')
    msgs = sample_messages()
    results = {}
    for comp in ('zstd', 'none'):
        bag = write_bag(tmp_path / comp, msgs, compression=comp, chunk_size=4000)
        ours = [(m.topic, m.msg_type, m.t_ns, bytes(m.msg)) for m in BagReader(bag).messages(raw=True)]
        for mode in ([], ['--stream']):
            res = subprocess.run(['node', str(NODE_READER), str(bag), *mode], capture_output=True, text=True, timeout=120)
            assert res.returncode == 0, res.stderr
            doc = json.loads(res.stdout)
            theirs = [(m['topic'], m['schema'], int(m['logTime']), base64.b64decode(m['data'])) for m in doc['messages']]
            if mode:    # stream order = file order; ours is time order (the same here, written in order)
                theirs.sort(key=lambda x: x[2])
            assert theirs == ours, (comp, mode)
            assert {c['topic'] for c in doc['channels']} == {m[0] for m in msgs}
            assert all(c['metadata']['topic_type_hash'].startswith('RIHS01_') for c in doc['channels'])
            assert [m['name'] for m in doc['metadata']] == ['rosbag2']
            schemas = {s['name']: s['data'] for s in doc['schemas']}
            assert schemas['hexapod_msgs/msg/ServoDiagnostics'] == bagio.message_definition('hexapod_msgs/msg/ServoDiagnostics')
            results[(comp, tuple(mode))] = len(theirs)
    assert set(results.values()) == {len(msgs)}
