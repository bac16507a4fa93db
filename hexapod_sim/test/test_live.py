"""The Foxglove live view: a WebSocket client (the ``websockets`` package, Foxglove's protocol)
connects, subscribes to every channel and receives the robot model, the transforms (equal to the
DH forward kinematics), joint states and ground-detection telemetry; from the recorder directly,
from ``sim_node -p foxglove:=true`` and from ``demo --foxglove``."""
import asyncio
import json
import os
import re
import struct
import subprocess
import sys
import threading
import time

import numpy as np
import pytest

from hexapod_model import contract
from hexapod_model.description import ALL_JOINTS, LEGS, load_robot
from hexapod_model.kinematics import leg_frames
from hexapod_model.tf_tree import matrix_of
from hexapod_model.urdf import urdf_xml

websockets = pytest.importorskip('websockets')
pytest.importorskip('foxglove')
from rosbags.typesys import Stores, get_types_from_msg, get_typestore  # noqa: E402

from hexapod_sim.bagio.recorder import Recorder  # noqa: E402
from hexapod_sim.node.live import LiveView, LiveViewError  # noqa: E402


def bag_topic(name: str) -> str:
    return contract.bag_topic(name)


# the live channels carry the bags' (and the README's) absolute names
WANTED = tuple(bag_topic(t) for t in (contract.ROBOT_DESCRIPTION, contract.TF_STATIC, contract.TF,
                                      contract.JOINT_STATES, contract.GROUND_DETECTION))


class Client:
    """Connects to a Foxglove WebSocket server in a thread of its own, subscribes to every channel
    it advertises and keeps what arrives: {topic: [(log_time_ns, payload)]} and the channel infos."""

    def __init__(self, url: str, wanted=WANTED, timeout: float = 60.0):
        self.url, self.wanted, self.timeout = url, set(wanted), timeout
        self.channels: dict[int, dict] = {}
        self.got: dict[str, list] = {}
        self.error: BaseException | None = None
        self.done = threading.Event()
        self._thread = threading.Thread(target=lambda: asyncio.run(self._run()), daemon=True)
        self._thread.start()

    async def _run(self):
        try:
            async with websockets.connect(self.url, subprotocols=['foxglove.sdk.v1'], max_size=None) as ws:
                subs: dict[int, str] = {}
                t_end = time.monotonic() + self.timeout
                while not self.wanted <= set(self.got):
                    msg = await asyncio.wait_for(ws.recv(), max(0.1, t_end - time.monotonic()))
                    if isinstance(msg, str):
                        doc = json.loads(msg)
                        if doc['op'] == 'advertise':
                            new = [c for c in doc['channels'] if c['id'] not in self.channels]
                            for c in new:
                                self.channels[c['id']] = c
                                subs[len(subs) + 1] = c['topic']
                            await ws.send(json.dumps({'op': 'subscribe', 'subscriptions': [
                                {'id': sid, 'channelId': cid} for sid, cid in
                                zip(range(len(subs) - len(new) + 1, len(subs) + 1), [c['id'] for c in new])]}))
                    elif msg[0] == 0x01:                     # message data
                        sid, t_ns = struct.unpack_from('<IQ', msg, 1)
                        self.got.setdefault(subs[sid], []).append((t_ns, bytes(msg[13:])))
        except BaseException as exc:             # noqa: BLE001 - reported by wait()
            self.error = exc
        finally:
            self.done.set()

    def wait(self):
        self.done.wait(self.timeout + 5)
        if self.error is not None:
            raise AssertionError(f'live view client: {self.error!r}; got {sorted(self.got)}') from self.error
        assert self.wanted <= set(self.got), sorted(self.got)

    def decode(self, topic: str):
        """Every message of ``topic`` decoded with the schema the server advertised (rosbags)."""
        ch = next(c for c in self.channels.values() if c['topic'] == topic)
        assert ch['encoding'] == 'cdr' and ch['schemaEncoding'] == 'ros2msg'
        store = get_typestore(Stores.EMPTY)
        parts = ch['schema'].split('=' * 80 + '\n')
        types = dict(get_types_from_msg(parts[0], ch['schemaName']))
        for part in parts[1:]:
            head, _, body = part.partition('\n')
            pkg, _, name = head.removeprefix('MSG: ').strip().rpartition('/')
            types.update(get_types_from_msg(body, f'{pkg}/msg/{name}'))
        store.register(types)
        return [(t, store.deserialize_cdr(data, ch['schemaName'])) for t, data in self.got[topic]]


def check_robot_and_tf(robot, client):
    (_, desc), *_ = client.decode(bag_topic(contract.ROBOT_DESCRIPTION))
    assert desc.data == urdf_xml(robot)
    fixed = {tr.child_frame_id: (tr.header.frame_id, matrix_of(tr.transform))
             for _, msg in client.decode(bag_topic(contract.TF_STATIC)) for tr in msg.transforms}
    _, last = client.decode(bag_topic(contract.TF))[-1]
    tree = {tr.child_frame_id: (tr.header.frame_id, matrix_of(tr.transform)) for tr in last.transforms}
    tree.update(fixed)

    def pose(frame, root):
        parent, m = tree[frame]
        return m if parent == root else pose(parent, root) @ m

    angles = {tr.child_frame_id: None for tr in last.transforms}
    assert {f'leg{leg}_{r}' for leg in LEGS for r in ('coxa', 'femur', 'tibia')} <= set(angles)
    return tree, pose


def test_recorder_feeds_the_live_view_and_a_client_receives_each_channel():
    robot = load_robot()
    view = LiveView(0)
    try:
        assert view.url.startswith('ws://127.0.0.1:')
        rec = Recorder(None, robot=robot, live=view)
        rng = np.random.default_rng(0)
        angles = rng.uniform(-0.6, 0.6, 18)
        client = Client(view.url)
        t = 0.0
        while not client.done.is_set() and t < 60.0:       # a robot walking on, 50 Hz
            rec.write_tf(t, ALL_JOINTS, angles, (np.array([t, 0, 0.1]), np.array([1.0, 0, 0, 0])))
            rec.write(contract.JOINT_STATES, contract.MSG_TYPES[contract.JOINT_STATES],
                      {'header': {'stamp': {'sec': 0, 'nanosec': 0}}, 'name': ['leg1_femur'],
                       'position': [float(angles[1])]}, t)
            rec.write(contract.GROUND_DETECTION, contract.MSG_TYPES[contract.GROUND_DETECTION],
                      {'leg': 1, 'detector': 'adaptive', 'err_tick': 4.0, 'threshold_tick': 3.5, 'stopped': True}, t)
            t += 0.02
            time.sleep(0.02)
        client.wait()
    finally:
        view.close()
    tree, pose = check_robot_and_tf(robot, client)
    for leg in LEGS:
        theta = angles[[ALL_JOINTS.index(f'leg{leg}_{r}') for r in ('coxa', 'femur', 'tibia')]]
        np.testing.assert_allclose(pose(f'leg{leg}_foot', 'base_link'), leg_frames(robot, leg, theta)[-1], atol=1e-12)
    (_, js), *_ = client.decode(bag_topic(contract.JOINT_STATES))
    assert list(js.name) == ['leg1_femur'] and js.position[0] == pytest.approx(angles[1])
    (_, gd), *_ = client.decode(bag_topic(contract.GROUND_DETECTION))
    assert gd.leg == 1 and gd.stopped and gd.err_tick == 4.0
    from hexapod_sim.node.live import LIVE_TOPICS
    assert {c['topic'] for c in client.channels.values()} == {bag_topic(t) for t in LIVE_TOPICS}
    assert '/ground_detection' in {c['topic'] for c in client.channels.values()}


def test_port_in_use_is_one_clear_error():
    view = LiveView(0)
    try:
        with pytest.raises(LiveViewError, match=f'127.0.0.1:{view.port}'):
            LiveView(view.port)
    finally:
        view.close()
    with pytest.raises(LiveViewError, match='0..65535'):
        LiveView(70000)


def _env(domain: int):
    return dict(os.environ, ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST', PYTHONUNBUFFERED='1')


def _url_from(proc, pattern, timeout=120.0):
    lines = []
    t_end = time.monotonic() + timeout
    while time.monotonic() < t_end:
        line = proc.stdout.readline()
        if not line:
            break
        lines.append(line)
        m = re.search(pattern, line)
        if m:
            threading.Thread(target=lambda: [lines.append(x) for x in proc.stdout], daemon=True).start()
            return m.group(1), lines
    raise AssertionError('no live view URL in the output:\n' + ''.join(lines))


def test_demo_foxglove_serves_the_walk():
    robot = load_robot()
    proc = subprocess.Popen([sys.executable, '-m', 'hexapod_locomotion.trials.demo', '--foxglove', '0', '--record', '',
                             '--duration', '6', '--terrain', 'flat', '--no-progress'],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=_env(90))
    try:
        url, lines = _url_from(proc, r'live view: (ws://127\.0\.0\.1:\d+)')
        client = Client(url, wanted=WANTED + (bag_topic(contract.ODOM),), timeout=90.0)
        client.wait()
    finally:
        proc.wait(timeout=180)
    assert proc.returncode == 0, ''.join(lines)
    tree, pose = check_robot_and_tf(robot, client)
    # the leg odometry's odom -> base_link, placed in the world by the sim's truth (world -> odom)
    assert tree['base_link'][0] == 'odom' and tree['odom'][0] == 'world'
    (_, odom), *_ = client.decode(bag_topic(contract.ODOM))
    assert odom.header.frame_id == 'odom' and odom.child_frame_id == 'base_link'
    assert client.decode(bag_topic(contract.GROUND_DETECTION))[0][1].detector == 'adaptive'


@pytest.mark.parametrize('namespace', [None, '/hexa'])
def test_sim_node_parameter_serves_the_live_view(namespace):
    """The channels have the bags' absolute names also when the node runs in a namespace."""
    robot = load_robot()
    ns = ['-r', f'__ns:={namespace}'] if namespace else []
    proc = subprocess.Popen([sys.executable, '-m', 'hexapod_sim.node.sim_node', '--ros-args', '-p', 'foxglove:=true',
                             '-p', 'foxglove_port:=0', '-p', 'truth_rate_hz:=100.0', *ns],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            env=_env(92 if namespace else 91))
    try:
        url, lines = _url_from(proc, r'Foxglove live view on (ws://127\.0\.0\.1:\d+)')
        # no controller runs: the sim reads every joint in turn; ground detection comes from a controller
        client = Client(url, wanted=set(WANTED) - {bag_topic(contract.GROUND_DETECTION)}, timeout=60.0)
        client.wait()
    finally:
        proc.send_signal(2)
        proc.wait(timeout=30)
    assert proc.returncode == 0, ''.join(lines)
    check_robot_and_tf(robot, client)
    topics = {c['topic'] for c in client.channels.values()}
    assert {'/robot_description', '/joint_states', '/ground_detection', '/tf', '/tf_static'} <= topics, topics
    assert all(t.startswith('/') and not t.startswith('/hexa') for t in topics), topics
