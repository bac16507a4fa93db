"""TF and the robot description in every bag, read back by independent readers: ``rosbags`` (Python)
and ``@mcap/core`` (Node.js, CDR decoded by rosbags): the transforms decode and chain to the forward
kinematics of the DH model (Eq. 1-3)."""
import base64
import json
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from hexapod_model import contract
from hexapod_model.description import ALL_JOINTS, LEGS, load_robot
from hexapod_model.kinematics import leg_frames
from hexapod_model.tf_tree import TfTree, matrix_of
from hexapod_model.urdf import urdf_xml
from hexapod_sim.bagio import BagWriter
from hexapod_sim.bagio.recorder import TF_RATE_HZ, Recorder, cdr_tf_entries

rosbags = pytest.importorskip('rosbags')
from rosbags.highlevel import AnyReader  # noqa: E402
from rosbags.typesys import Stores, get_types_from_msg, get_typestore  # noqa: E402

REPO = Path(__file__).resolve().parents[2]


@pytest.fixture(scope='module')
def robot():
    return load_robot()


def _stamp(t):
    ns = int(round(t * 1e9))
    return {'sec': ns // 1_000_000_000, 'nanosec': ns % 1_000_000_000}


def _pose(xyz, quat_wxyz):
    m = np.eye(4)
    w, x, y, z = quat_wxyz
    m[:3, :3] = Rotation.from_quat([x, y, z, w]).as_matrix()
    m[:3, 3] = xyz
    return m


def _record(path, robot, rng, seconds=0.4):
    """1 kHz /joint_states (one joint per message, as the bus reads) and a 100 Hz body pose."""
    truth = []                  # (t, angles of ALL_JOINTS as last read, body pose)
    angles = np.array([rng.uniform(*robot.joint_limits(j)) for j in ALL_JOINTS])
    pose = (np.zeros(3), np.array([1.0, 0, 0, 0]))
    with Recorder(path, robot=robot) as rec:
        for k in range(int(seconds * 1000)):
            t = 0.1 + k * 0.001
            i = k % len(ALL_JOINTS)
            angles[i] = rng.uniform(*robot.joint_limits(ALL_JOINTS[i]))
            if k % 10 == 0:
                q = Rotation.from_euler('xyz', rng.uniform(-0.2, 0.2, 3)).as_quat()    # x y z w
                pose = (np.array([t * 0.1, 0.01, 0.12]), np.array([q[3], q[0], q[1], q[2]]))
                rec.write(contract.SIM_TRUTH_POSE, contract.MSG_TYPES[contract.SIM_TRUTH_POSE], {
                    'header': {'stamp': _stamp(t), 'frame_id': 'world'},
                    'pose': {'position': dict(zip('xyz', pose[0].tolist())),
                             'orientation': dict(zip('wxyz', pose[1].tolist()))}}, t)
            rec.write(contract.JOINT_STATES, contract.MSG_TYPES[contract.JOINT_STATES],
                      {'header': {'stamp': _stamp(t)}, 'name': [ALL_JOINTS[i]], 'position': [float(angles[i])]}, t)
            truth.append((int(round(t * 1e9)), angles.copy(), pose))
    return truth


def _check_tf(robot, tf_msgs, static, truth):
    """Every /tf message chains world -> foot of every leg to the DH forward kinematics of the
    joint angles last read at its time, placed at the body pose."""
    fixed = {tr.child_frame_id: (tr.header.frame_id, matrix_of(tr.transform)) for tr in static.transforms}
    assert set(fixed) == {'trunk'} | {f'leg{leg}_foot' for leg in LEGS}
    by_t = {t: (a, p) for t, a, p in truth}
    assert len(tf_msgs) >= 0.9 * TF_RATE_HZ * (truth[-1][0] - truth[0][0]) / 1e9
    t_all_read = truth[len(ALL_JOINTS) - 1][0]         # until then only the joints read so far move
    for t_ns, msg in tf_msgs:
        angles, pose = by_t[t_ns]
        tree = {tr.child_frame_id: (tr.header.frame_id, matrix_of(tr.transform)) for tr in msg.transforms}
        assert all(tr.header.stamp.sec * 10**9 + tr.header.stamp.nanosec == t_ns for tr in msg.transforms)
        tree.update(fixed)
        if t_ns < t_all_read:
            assert len(tree) < 1 + 1 + 18 + 6
            continue
        assert len(tree) == 1 + 1 + 18 + 6

        def world(frame):
            parent, m = tree[frame]
            return m if parent == 'world' else world(parent) @ m

        np.testing.assert_allclose(world('base_link'), _pose(*pose), atol=1e-12)
        for leg in LEGS:
            theta = angles[[ALL_JOINTS.index(f'leg{leg}_{r}') for r in ('coxa', 'femur', 'tibia')]]
            fk = _pose(*pose) @ leg_frames(robot, leg, theta)[-1]
            np.testing.assert_allclose(world(f'leg{leg}_foot'), fk, atol=1e-12)


def test_bag_carries_tf_and_robot_description_read_by_rosbags(tmp_path, robot):
    bag = tmp_path / 'tfbag'
    truth = _record(bag, robot, np.random.default_rng(0))
    with AnyReader([bag]) as reader:            # rosbags: its own MCAP reader and CDR decoder
        conns = {c.topic: c for c in reader.connections}
        assert conns['/tf'].msgtype == 'tf2_msgs/msg/TFMessage'
        assert conns['/tf_static'].msgtype == 'tf2_msgs/msg/TFMessage'
        assert conns['/robot_description'].msgtype == 'std_msgs/msg/String'
        got = {}
        for conn, t_ns, raw in reader.messages(connections=[conns[t] for t in ('/tf', '/tf_static',
                                                                              '/robot_description')]):
            got.setdefault(conn.topic, []).append((t_ns, reader.deserialize(raw, conn.msgtype)))
    (_, desc), = got['/robot_description']
    assert desc.data == urdf_xml(robot)
    (_, static), = got['/tf_static']
    _check_tf(robot, got['/tf'], static, truth)
    meta = (bag / 'metadata.yaml').read_text()
    assert 'transient_local' in meta                    # latched like their publishers


def test_tf_decoded_from_mcap_core_equals_forward_kinematics(tmp_path, robot):
    if shutil.which('node') is None:
        pytest.skip('node is not installed: the @mcap/core cross-check needs Node.js')
    reader_js = REPO / 'tools' / 'mcap-node' / 'read.mjs'
    if not (REPO / 'tools' / 'mcap-node' / 'node_modules' / '@mcap' / 'core').is_dir():
        pytest.skip('tools/mcap-node (@mcap/core) not set up; ./hexapod setup runs npm ci')
    bag = tmp_path / 'tfbag'
    truth = _record(bag, robot, np.random.default_rng(1), seconds=0.2)
    res = subprocess.run(['node', str(reader_js), str(bag)], capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stderr
    doc = json.loads(res.stdout)
    schemas = {s['id']: s for s in doc['schemas']} if isinstance(doc['schemas'], list) else doc['schemas']
    assert any(s['name'] == 'tf2_msgs/msg/TFMessage' for s in
               (schemas.values() if isinstance(schemas, dict) else schemas))
    # CDR decoded by rosbags with the type registered from the schema text the bag carries
    store = get_typestore(Stores.EMPTY)
    tf_schema = next(s for s in (schemas.values() if isinstance(schemas, dict) else schemas)
                     if s['name'] == 'tf2_msgs/msg/TFMessage')
    text = tf_schema['data'] if isinstance(tf_schema['data'], str) else base64.b64decode(tf_schema['data']).decode()
    store.register(_types_of_concatenated_msg(text, 'tf2_msgs/msg/TFMessage'))
    tf_msgs, static = [], None
    for m in doc['messages']:
        if m['topic'] in ('/tf', '/tf_static'):
            msg = store.deserialize_cdr(base64.b64decode(m['data']), 'tf2_msgs/msg/TFMessage')
            if m['topic'] == '/tf':
                tf_msgs.append((int(m['logTime']), msg))
            else:
                static = msg
    _check_tf(robot, tf_msgs, static, truth)


def _types_of_concatenated_msg(text: str, name: str) -> dict:
    """rosbags types of a ros2msg schema (the type, then '====' and 'MSG: pkg/Name' sections)."""
    types = {}
    parts = text.split('=' * 80 + '\n')
    types.update(get_types_from_msg(parts[0], name))
    for part in parts[1:]:
        head, _, body = part.partition('\n')
        sub = head.removeprefix('MSG: ').strip()
        pkg, _, short = sub.rpartition('/')
        types.update(get_types_from_msg(body, f'{pkg}/msg/{short}'))
    return types


def test_truth_from_the_simulator_replaces_joint_states(tmp_path, robot):
    bag = tmp_path / 'truth'
    rng = np.random.default_rng(2)
    angles = rng.uniform(-0.5, 0.5, 18)
    with Recorder(bag, robot=robot) as rec:
        assert rec.tf_due(0.0)
        rec.write_tf(0.0, ALL_JOINTS, angles, (np.array([0.0, 0.0, 0.1]), np.array([1.0, 0, 0, 0])))
        assert not rec.tf_due(0.001) and rec.tf_due(1 / TF_RATE_HZ)
        for t in (0.03, 0.05):                   # past the next due time: no /tf of measured joints
            rec.write(contract.JOINT_STATES, contract.MSG_TYPES[contract.JOINT_STATES],
                      {'header': {'stamp': _stamp(t)}, 'name': ['leg1_coxa'], 'position': [0.9]}, t)
    with AnyReader([bag]) as reader:
        tfs = [reader.deserialize(raw, c.msgtype) for c, _, raw in reader.messages()
               if c.topic == '/tf']
    assert len(tfs) == 1
    expect = TfTree(robot)
    expect.set_positions(ALL_JOINTS, angles)
    want = {e[1]: e[3] for e in expect.dynamic_entries()}
    for tr in tfs[0].transforms[1:]:
        r = tr.transform.rotation
        assert [r.x, r.y, r.z, r.w] == pytest.approx(want[tr.child_frame_id], abs=1e-15)


def test_tf_packer_matches_the_bag_writers_encoder(tmp_path, robot):
    tree = TfTree(robot)
    tree.set_positions(ALL_JOINTS, np.linspace(-0.5, 0.5, 18))
    tree.set_body_pose([0.1, 0.2, 0.3], [0.9, 0.1, 0.2, 0.3])
    entries = tree.dynamic_entries()
    fast = cdr_tf_entries([(3, 7, *e) for e in entries])
    w = BagWriter(tmp_path / 'enc')
    try:
        w.write('/tf', 'tf2_msgs/msg/TFMessage', tree.dynamic_message(3.000000007), 1)
        generic = w._encode(w._topics['/tf'], tree.dynamic_message(3.000000007))
    finally:
        w.close()
    assert fast == generic


def test_tf_of_a_simulated_walk_puts_the_feet_where_mujoco_has_them(tmp_path, robot):
    """The sim's truth written as TF (as the demo and sim_node do) chains world -> foot to MuJoCo's
    own foot-tip sites: URDF, DH and MJCF agree on where every foot is."""
    import mujoco

    from hexapod_sim.physics.plant import HexapodSim, run_trajectory
    from hexapod_sim.tools.render import scripted_tripod
    sim = HexapodSim(robot, terrain='flat')
    sites = [mujoco.mj_name2id(sim.model, mujoco.mjtObj.mjOBJ_SITE, f'leg{leg}_foot_tip') for leg in LEGS]
    feet = {}
    bag = tmp_path / 'walk'
    with Recorder(bag, robot=robot) as rec:
        def on_period(s):
            if rec.tf_due(s.now()):
                s.refresh_derived()
                feet[int(round(s.now() * 1e9))] = s.data.site_xpos[sites].copy()
                rec.write_tf(s.now(), ALL_JOINTS, s.true_joint_angles(), s.body_pose())
        run_trajectory(sim, scripted_tripod(robot), 2.0, period_s=0.01, on_period=on_period)
    with AnyReader([bag]) as reader:
        static = {}
        tfs = []
        for conn, t_ns, raw in reader.messages(connections=[c for c in reader.connections
                                                            if c.topic in ('/tf', '/tf_static')]):
            msg = reader.deserialize(raw, conn.msgtype)
            if conn.topic == '/tf_static':
                static = {tr.child_frame_id: (tr.header.frame_id, matrix_of(tr.transform)) for tr in msg.transforms}
            else:
                tfs.append((t_ns, msg))
    assert len(tfs) == len(feet) >= 2.0 * TF_RATE_HZ
    lifted = 0.0
    for t_ns, msg in tfs:
        tree = {tr.child_frame_id: (tr.header.frame_id, matrix_of(tr.transform)) for tr in msg.transforms}
        tree.update(static)

        def world(frame):
            parent, m = tree[frame]
            return m if parent == 'world' else world(parent) @ m
        got = np.array([world(f'leg{leg}_foot')[:3, 3] for leg in LEGS])
        np.testing.assert_allclose(got, feet[t_ns], atol=1e-9)
        lifted = max(lifted, float(np.ptp(got[:, 2])))
    assert lifted > 0.02                                   # the tripod lifts its feet: a real motion
