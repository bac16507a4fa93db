"""Bag I/O reading: truncation, corrupt chunks, garbage, unknown types, joint series, cross-reader checks."""
import base64
import io
import json
import os
import random
import shutil
import subprocess
import warnings

import numpy as np
import pytest
from bag_samples import JS, NODE_READER, REPO, T0, as_plain, assert_subset, joint_state, sample_messages, write_bag
from mcap.exceptions import EndOfFile
from mcap.reader import make_reader
from mcap.records import Message
from mcap.stream_reader import StreamReader

from hexapod_model import contract
from hexapod_model.joints import Joint
from hexapod_sim import bagio
from hexapod_sim.bagio import BagError, BagReader, BagWarning, BagWriter

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

FEMUR1 = Joint(1, 'femur')


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
    # the log time it lost: from the last message before the chunk to the first after it
    assert reader.lost_spans == [(T0 + lost_from - 1, T0 + lost_from + n2)]
    assert BagReader(write_bag(tmp_path / 'whole', msgs)).lost_spans == []


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

def test_joint_series_per_joint(tmp_path):
    with BagWriter(tmp_path / 'b') as w:
        for k in range(5):
            t = T0 + k * 4_000_000
            w.write(contract.JOINT_COMMANDS, JS, joint_state(t, ['leg1_coxa', 'leg1_femur'], [0.1 * k, 0.2 * k]), t)
            # one read per message, stamped at the sample time (earlier than the record time)
            w.write(contract.JOINT_STATES, JS, joint_state(t + 1_000_000, ['leg1_femur'], [0.2 * k - 0.05]), t + 1_500_000)
    bag = bagio.load_bag(tmp_path / 'b')
    js = {contract.JOINT_COMMANDS: bag.joint_commands.per_joint(), contract.JOINT_STATES: bag.joint_states.per_joint()}
    base = T0 / 1e9
    femur_cmd = js[contract.JOINT_COMMANDS][FEMUR1]
    assert femur_cmd.shape == (5, 2)
    np.testing.assert_allclose(femur_cmd[:, 0] - base, [0.0, 0.004, 0.008, 0.012, 0.016], atol=1e-6)
    np.testing.assert_allclose(femur_cmd[:, 1], [0.0, 0.2, 0.4, 0.6, 0.8])
    meas = js[contract.JOINT_STATES]
    assert list(meas) == [FEMUR1]
    np.testing.assert_allclose(meas[FEMUR1][:, 0] - base, [0.001, 0.005, 0.009, 0.013, 0.017], atol=1e-6)
    with BagWriter(tmp_path / 'bad') as w:
        w.write(contract.JOINT_STATES, JS, joint_state(T0, ['a', 'b'], [1.0]), T0)
    with pytest.raises(BagError, match='names 2 joint'):
        bagio.load_bag(tmp_path / 'bad')
    with BagWriter(tmp_path / 'foreign') as w:
        w.write(contract.JOINT_STATES, JS, joint_state(T0, ['leg7_femur'], [1.0]), T0)
    with pytest.raises(BagError, match="unknown joint: joint name 'leg7_femur' is not of the form"):
        bagio.load_bag(tmp_path / 'foreign').joint_states.per_joint()


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
        assert bagio.load_bag(tmp_path / name).joint_states.per_joint()[FEMUR1][0, 1] == 0.5
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
