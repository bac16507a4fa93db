"""Recording of the sim node's topics into a rosbag2-layout MCAP bag (``bags/`` by default). No rclpy.

A thin layer over :class:`hexapod_sim.bagio.BagWriter`: the node hands every message it
publishes or receives to :meth:`Recorder.write` with the simulated time as the log time. The
writer closes its chunk, flushes and rewrites ``metadata.yaml`` at least every :data:`FLUSH_PERIOD_S`
of simulated *and* of wall time, so a crash of the writer loses at most that; :meth:`close` finalises
the bag (MCAP summary and final metadata).

ROS message instances are converted to plain dicts (:func:`ros_to_plain`) and CDR-encoded by the
bag writer's own encoder, not by ``rclpy.serialization``: on Jazzy with Fast DDS the latter
returns ``sensor_msgs/JointState`` followed by 8 uninitialised bytes (and garbage in alignment
padding), which the ``rosbags`` reader rejects ("CDR message size mismatch"). The high-rate
types (JointState and Clock at 1 kHz, Imu at 400 Hz, the 100 Hz truth topics) are packed directly
by the ``cdr_*`` functions below (little-endian CDR, zero padding; a test checks them byte for
byte against the bag writer's encoder): the generic encoder is pure Python and would cap the
recording rate.

Every bag also carries the robot for 3D views (Foxglove, RViz): ``/robot_description`` (the URDF
of the robot description, std_msgs/String) and ``/tf_static`` (the URDF's fixed joints), both
once at the first message and offered transient local as their publishers do, and ``/tf``
(tf2_msgs/TFMessage) at :data:`TF_RATE_HZ` of log time: ``world -> base_link`` from
``/sim/body_pose`` and ``base_link -> ... -> leg{l}_{role}`` from the latest ``/joint_states`` of
each joint, or from the true joint angles a simulator hands to :meth:`Recorder.write_tf`.

:class:`RecorderThread` runs a :class:`Recorder` in a thread of the caller's process, fed through a
queue; :class:`hexapod_sim.bagio.recorder_process.RecorderProcess` runs one in a child process. In
either, the callers never wait for the conversion, the bag writer or its periodic flush.
"""
from __future__ import annotations

import collections
import datetime as _dt
import os
import struct
import threading
from pathlib import Path
from typing import Any

from hexapod_model import contract
from hexapod_model.description import Robot, load_robot
from hexapod_model.tf_tree import TfTree
from hexapod_model.urdf import urdf_xml
from hexapod_sim.bagio import DEFAULT_QOS_PROFILE, BagError, BagWriter, encode_message

FLUSH_PERIOD_S = 0.5          # [s] of log time the writer may hold unflushed: lost in a power cut
TF_RATE_HZ = 50.0             # /tf in log time: smooth in Foxglove, ~20 % of the bag's messages
MAX_QUEUED = 20_000           # RecorderThread: messages waiting for the writer (~6 s of the robot's) before callers wait
LATCHED_QOS = {**DEFAULT_QOS_PROFILE, 'depth': 1, 'durability': 'transient_local'}


def default_bag_root() -> Path:
    """``bags/`` of the workspace (``$HEXAPOD_BAGS`` overrides): the folder next to the packages."""
    env = os.environ.get('HEXAPOD_BAGS')
    if env:
        return Path(env)
    here = Path(__file__).resolve()
    for parent in here.parents:            # source tree or symlink install: find the workspace root
        if (parent / 'bags').is_dir() and (parent / 'hexapod_sim').is_dir():
            return parent / 'bags'
    return Path.cwd() / 'bags'


def resolve_bag_dir(spec: str, prefix: str = 'sim') -> Path:
    """The bag directory for a ``record`` parameter value.

    ``'auto'``: ``bags/<prefix>_<UTC timestamp>``; a bare name: ``bags/<name>``; a path with a
    slash: used as given.
    """
    if not spec:
        raise ValueError('empty record path: recording is off')
    if spec == 'auto':
        stamp = _dt.datetime.now(_dt.timezone.utc).strftime('%Y%m%dT%H%M%S')
        return default_bag_root() / f'{prefix}_{stamp}'
    if '/' not in spec:
        return default_bag_root() / spec
    return Path(spec)


class RecorderError(ValueError):
    """A bag cannot be recorded at the requested place (the message says why)."""


def check_bag_dir(path: str | os.PathLike) -> Path:
    """``path`` if a new bag can be recorded there (what :class:`Recorder` would refuse, checked
    before a run starts, without creating anything)."""
    p = Path(path)
    if p.suffix == '.mcap':
        raise RecorderError(f'{p}: a bag is a directory; give a path without the .mcap suffix')
    if p.exists() and (not p.is_dir() or any(p.iterdir())):
        raise RecorderError(f'{p} already exists and is not an empty directory; refusing to overwrite a recording')
    anc = next((a for a in [p, *p.parents] if a.exists()), Path('.'))
    if not anc.is_dir() or not os.access(anc, os.W_OK):
        raise RecorderError(f'{p}: cannot create it ({anc} is not a writable directory)')
    return p


def ros_to_plain(msg: Any) -> Any:
    """A ROS message instance (rosidl Python class) as nested dicts/lists of plain values."""
    fields = getattr(type(msg), 'get_fields_and_field_types', None)
    if fields is not None:
        return {name: ros_to_plain(getattr(msg, name)) for name in fields()}
    if isinstance(msg, (str, bytes, bool, int, float)):
        return msg
    if isinstance(msg, (list, tuple)):
        return [ros_to_plain(v) for v in msg]
    if hasattr(msg, 'tolist'):             # numpy arrays and array.array of numeric fields
        return msg.tolist()
    return msg


_CDR_LE = b'\x00\x01\x00\x00'          # encapsulation header: plain CDR, little endian
_TIME = struct.Struct('<iI')


def cdr_clock(msg) -> bytes:
    """``rosgraph_msgs/msg/Clock`` as CDR."""
    return _CDR_LE + _TIME.pack(msg.clock.sec, msg.clock.nanosec)


def _pad(buf: bytearray, align: int) -> None:
    buf.extend(b'\x00' * (-(len(buf) - 4) % align))       # alignment counts from the end of the header


def _string(buf: bytearray, text: str) -> None:
    data = text.encode() + b'\x00'
    _pad(buf, 4)
    buf.extend(struct.pack('<I', len(data)))
    buf.extend(data)


def _doubles(buf: bytearray, values) -> None:
    _pad(buf, 4)
    buf.extend(struct.pack('<I', len(values)))
    if len(values):
        _pad(buf, 8)
        buf.extend(struct.pack(f'<{len(values)}d', *values))


def cdr_joint_state(msg) -> bytes:
    """``sensor_msgs/msg/JointState`` as CDR."""
    buf = bytearray(_CDR_LE)
    buf.extend(_TIME.pack(msg.header.stamp.sec, msg.header.stamp.nanosec))
    _string(buf, msg.header.frame_id)
    _pad(buf, 4)
    buf.extend(struct.pack('<I', len(msg.name)))
    for name in msg.name:
        _string(buf, name)
    for seq in (msg.position, msg.velocity, msg.effort):
        _doubles(buf, seq)
    return bytes(buf)


def _header(buf: bytearray, header) -> None:
    buf.extend(_TIME.pack(header.stamp.sec, header.stamp.nanosec))
    _string(buf, header.frame_id)


def _fixed_doubles(buf: bytearray, values) -> None:
    _pad(buf, 8)
    buf.extend(struct.pack(f'<{len(values)}d', *values))


def cdr_imu(msg) -> bytes:
    """``sensor_msgs/msg/Imu`` as CDR."""
    buf = bytearray(_CDR_LE)
    _header(buf, msg.header)
    o, w, a = msg.orientation, msg.angular_velocity, msg.linear_acceleration
    _fixed_doubles(buf, (o.x, o.y, o.z, o.w, *msg.orientation_covariance, w.x, w.y, w.z,
                         *msg.angular_velocity_covariance, a.x, a.y, a.z, *msg.linear_acceleration_covariance))
    return bytes(buf)


def cdr_pose_stamped(msg) -> bytes:
    """``geometry_msgs/msg/PoseStamped`` as CDR."""
    buf = bytearray(_CDR_LE)
    _header(buf, msg.header)
    p, q = msg.pose.position, msg.pose.orientation
    _fixed_doubles(buf, (p.x, p.y, p.z, q.x, q.y, q.z, q.w))
    return bytes(buf)


def cdr_float64_multi_array(msg) -> bytes:
    """``std_msgs/msg/Float64MultiArray`` as CDR."""
    buf = bytearray(_CDR_LE)
    buf.extend(struct.pack('<I', len(msg.layout.dim)))
    for d in msg.layout.dim:
        _string(buf, d.label)
        _pad(buf, 4)
        buf.extend(struct.pack('<II', d.size, d.stride))
    _pad(buf, 4)
    buf.extend(struct.pack('<I', msg.layout.data_offset))
    _doubles(buf, msg.data)
    return bytes(buf)


def cdr_tf_entries(entries) -> bytes:
    """``tf2_msgs/msg/TFMessage`` as CDR from (sec, nanosec, parent, child, xyz, quat xyzw) tuples."""
    buf = bytearray(_CDR_LE)
    buf.extend(struct.pack('<I', len(entries)))
    for sec, nsec, parent, child, xyz, q in entries:
        _pad(buf, 4)
        buf.extend(_TIME.pack(sec, nsec))
        _string(buf, parent)
        _string(buf, child)
        _fixed_doubles(buf, (*xyz, *q))
    return bytes(buf)


_FAST = {'sensor_msgs/msg/JointState': cdr_joint_state, 'rosgraph_msgs/msg/Clock': cdr_clock,
         'sensor_msgs/msg/Imu': cdr_imu, 'geometry_msgs/msg/PoseStamped': cdr_pose_stamped,
         'std_msgs/msg/Float64MultiArray': cdr_float64_multi_array}


class Recorder:
    """Write messages of several topics to one bag; times are nanoseconds of simulated time.

    ``robot``: the robot of the URDF and TF (default: the packaged description); ``tf_rate_hz`` 0
    records neither TF nor the robot description. ``bag_dir`` None writes no bag: only the ``live``
    view (:class:`hexapod_sim.node.live.LiveView`) gets the messages.
    """

    def __init__(self, bag_dir: str | os.PathLike | None, flush_period_s: float = FLUSH_PERIOD_S,
                 robot: Robot | None = None, tf_rate_hz: float = TF_RATE_HZ, live=None, scene: str | None = None,
                 **writer_kw: Any):
        self.path = Path(bag_dir) if bag_dir is not None else None
        self._scene = scene                        # the sim's ground (/sim/scene text), written once at the start
        self.live = live                           # a hexapod_sim.node.live.LiveView also gets every message
        self._tf = TfTree(robot if robot is not None else load_robot()) if tf_rate_hz > 0 else None
        self._tf_period_ns = int(round(1e9 / tf_rate_hz)) if tf_rate_hz > 0 else 0
        self._next_tf_ns: int | None = None        # None: robot description and /tf_static not yet written
        self._tf_truth = False                     # joint angles come from write_tf(), not /joint_states
        self._last_t_ns: int | None = None         # latest log time written (a /tf of it may be due)
        self._writer = BagWriter(self.path, flush_period_s=flush_period_s, **writer_kw) if self.path else None
        self._emitted = 0

    def write(self, topic: str, msg_type: str, msg: Any, t_s: float) -> None:
        """Record ``msg`` (a ROS message or a nested dict) on ``topic`` at simulated time ``t_s``."""
        t_ns = int(round(t_s * 1e9))
        if self._tf is not None:
            self._robot_once(t_ns)
            last = self._last_t_ns
            if last is not None and t_ns > last and last >= self._next_tf_ns and not self._tf_truth:
                self._write_tf(last)        # the state after every message of time ``last``
            self._track(topic, msg)
            self._last_t_ns = t_ns if last is None else max(last, t_ns)
        if hasattr(type(msg), 'get_fields_and_field_types'):
            fast = _FAST.get(msg_type)
            msg = fast(msg) if fast is not None else ros_to_plain(msg)
        self._emit(topic, msg_type, msg, t_ns)

    def _emit(self, topic: str, msg_type: str, msg: Any, t_ns: int) -> None:
        if self.live is not None:
            if not isinstance(msg, bytes):
                msg = encode_message(msg_type, msg)      # once, for the bag and the live view
            self.live.log(topic, msg_type, msg, t_ns)
        if self._writer is not None:
            self._writer.write(topic, msg_type, msg, t_ns)
        self._emitted += 1

    @property
    def count(self) -> int:
        """Messages in the bag (once a write failed: those it kept), or handed to the live view."""
        return self._writer.message_count if self._writer is not None else self._emitted

    def tf_due(self, t_s: float) -> bool:
        """True when the next /tf message is due at ``t_s`` (so a simulator fetches its truth only then)."""
        return self._tf is not None and (self._next_tf_ns is None or int(round(t_s * 1e9)) >= self._next_tf_ns)

    def write_tf(self, t_s: float, joint_names, joint_angles, body_pose=None) -> None:
        """Record /tf at ``t_s`` from true joint angles and body pose ``(xyz, quat wxyz)``; from then on
        /joint_states no longer move the recorded links (the truth is the better picture)."""
        if self._tf is None:
            return
        t_ns = int(round(t_s * 1e9))
        self._tf_truth = True
        self._tf.set_positions(joint_names, [float(v) for v in joint_angles])
        if body_pose is not None:
            self._tf.set_body_pose(*body_pose)
        self._robot_once(t_ns)
        self._write_tf(t_ns)

    def _track(self, topic: str, msg: Any) -> None:
        get = (lambda o, k: o[k]) if isinstance(msg, dict) else getattr
        if topic == contract.JOINT_STATES and not self._tf_truth:
            self._tf.set_positions(get(msg, 'name'), get(msg, 'position'))
        elif topic == contract.ODOM:
            pose, h = get(get(msg, 'pose'), 'pose'), get(msg, 'header')
            p, q = get(pose, 'position'), get(pose, 'orientation')
            self._tf.set_odom_pose(get(h, 'frame_id'), get(msg, 'child_frame_id'), [get(p, k) for k in 'xyz'],
                                   [get(q, k) for k in 'xyzw'])
        elif topic == contract.SIM_TRUTH_POSE and not self._tf_truth:
            pose = get(msg, 'pose')
            p, q = get(pose, 'position'), get(pose, 'orientation')
            self._tf.set_body_pose([get(p, k) for k in 'xyz'], [get(q, k) for k in 'wxyz'])

    def _robot_once(self, t_ns: int) -> None:
        if self._next_tf_ns is not None:
            return
        self._next_tf_ns = t_ns
        sec, nsec = divmod(t_ns, 1_000_000_000)
        latched = (contract.ROBOT_DESCRIPTION, contract.TF_STATIC) + ((contract.SIM_SCENE,) if self._scene else ())
        if self._writer is not None:
            for topic in latched:
                self._writer.add_topic(topic, contract.MSG_TYPES[topic], qos_profiles=[LATCHED_QOS])
        if self._scene:
            self._emit(contract.SIM_SCENE, contract.MSG_TYPES[contract.SIM_SCENE], {'data': self._scene}, t_ns)
        self._emit(contract.ROBOT_DESCRIPTION, contract.MSG_TYPES[contract.ROBOT_DESCRIPTION],
                   {'data': urdf_xml(self._tf.robot)}, t_ns)
        self._emit(contract.TF_STATIC, contract.MSG_TYPES[contract.TF_STATIC],
                   cdr_tf_entries([(sec, nsec, *e) for e in self._tf.static_entries()]), t_ns)

    def _write_tf(self, t_ns: int) -> None:
        entries = self._tf.dynamic_entries()
        self._next_tf_ns = max(self._next_tf_ns, t_ns - t_ns % self._tf_period_ns + self._tf_period_ns)
        if not entries:
            return
        sec, nsec = divmod(t_ns, 1_000_000_000)
        self._emit(contract.TF, contract.MSG_TYPES[contract.TF], cdr_tf_entries([(sec, nsec, *e) for e in entries]),
                   t_ns)

    def close(self) -> None:
        if self._tf is not None and self._last_t_ns is not None and self._last_t_ns >= self._next_tf_ns \
                and not self._tf_truth:
            self._write_tf(self._last_t_ns)
        if self._writer is not None:
            self._writer.close()

    def __enter__(self) -> 'Recorder':
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def _write_queued(rec: 'Recorder', item) -> str | None:
    """Write one queued item (a message, or a /tf request written when due) to ``rec``; the error in one
    line, or None. An error is reported once; the robot runs on."""
    try:
        if item[0] is None:
            _, names, angles, pose, t_s = item
            if rec.tf_due(t_s):
                rec.write_tf(t_s, names, angles, pose)
        else:
            rec.write(*item)
    except Exception as exc:               # noqa: BLE001 - reported once, the robot runs on
        text = one_line(exc)
        if rec.path is not None and text.startswith(str(rec.path)):     # a write error names the bag already
            return text
        return f'{item[0] or contract.TF}: {text}'
    return None


END_QUEUE_WAIT_S = 1.0         # [s] a queue lock held this long at close was left taken (see _end_queue)


class _QueuedWrites:
    """The writing side of a recorder that queues (:class:`RecorderThread`, :class:`~hexapod_sim.bagio.recorder_process.RecorderProcess`):
    both take messages and /tf requests through their own bounded queue, ``_put``."""

    _wake_at = 1                # queued items at which the writer is woken (the process sends in batches)

    def _behind(self, t_s: float) -> bool:
        """True while a message at log time ``t_s`` must wait for the writer to catch up (besides a full
        queue); called with the queue's lock held."""
        return False

    def _queued(self, t_s: float) -> None:
        """A message at log time ``t_s`` joined the queue (called with its lock held)."""

    def _put(self, item) -> None:
        """Queue ``item``, waiting for room; dropped once the queue is closed, ended or failed."""
        with self._not_full:
            while ((len(self._items) >= self._max or self._behind(item[-1]))
                   and not (self._closed or self._ended or self.error is not None)):
                self._not_full.wait()
            if self._closed or self._ended or self.error is not None:
                return
            self._items.append(item)
            self._queued(item[-1])
            if len(self._items) >= self._wake_at:   # otherwise the writer takes them at its next period
                self._not_empty.notify()

    def write(self, topic: str, msg_type: str, msg: Any, t_s: float) -> None:
        """:meth:`Recorder.write`, queued; dropped once closed or failed."""
        self._put((topic, msg_type, msg, t_s))

    def write_tf_if_due(self, t_s: float, joint_names, joint_angles, body_pose=None) -> None:
        """:meth:`Recorder.write_tf`, queued, when a /tf is due at ``t_s`` (:meth:`Recorder.tf_due`)."""
        self._put((None, joint_names, joint_angles, body_pose, t_s))

    _tf_next_ns = 0             # when the next /tf may be due, as far as this side knows

    def tf_due(self, t_s: float) -> bool:
        """True when a /tf may be due at ``t_s``: :meth:`Recorder.tf_due` of the writer's side, which
        this side cannot ask, judged from the /tf it asked for (:meth:`write_tf`) at the same rate.
        It is never False where the writer's would be True, and the writer checks again, so a caller
        of ``if tf_due(t): write_tf(t, ...)`` records what the same calls on a :class:`Recorder` would."""
        return int(round(t_s * 1e9)) >= self._tf_next_ns

    def write_tf(self, t_s: float, joint_names, joint_angles, body_pose=None) -> None:
        """:meth:`write_tf_if_due` (the writer writes it if it is due on its side)."""
        t_ns = int(round(t_s * 1e9))
        period = int(round(1e9 / TF_RATE_HZ))
        self._tf_next_ns = max(self._tf_next_ns, t_ns - t_ns % period + period)
        self.write_tf_if_due(t_s, joint_names, joint_angles, body_pose)

    def _report(self, text: str) -> None:
        """Tell ``on_error`` (if any) that the recording failed; a failing report must not end the writer."""
        if self.on_error is not None:
            try:
                self.on_error(text)
            except Exception:              # noqa: BLE001 - the robot runs on
                pass

    def _end_queue(self) -> bool:
        """Mark the queue closed and wake its waiters (callers waiting for room: their messages are
        dropped); False if it was closed already.

        The queue's lock is only ever held for a moment (waiters give it up while they wait), so one still
        held after ``END_QUEUE_WAIT_S`` was left taken: Ctrl-C's KeyboardInterrupt can arrive in a writer
        after the lock was taken and before its ``with`` block began, and nothing gives it back. The close
        then takes it over, or the recording would never end."""
        self._not_full.acquire(timeout=END_QUEUE_WAIT_S)
        try:
            if self._closed:
                return False
            self._closed = True
            self._not_empty.notify()
            self._not_full.notify_all()
        finally:
            self._not_full.release()
        return True


class RecorderThread(_QueuedWrites):
    """A :class:`Recorder` written by a thread of its own, fed through a queue (thread safe).

    :meth:`write` and :meth:`write_tf_if_due` only enqueue (the message objects must not change
    afterwards: the sim node makes a new one per message); the thread converts and writes them in
    the order they were enqueued, so the bag holds what the same calls on the :class:`Recorder`
    would have written. :meth:`close` writes everything enqueued before it, then closes the bag; a
    write that comes once :meth:`close` has begun is dropped, also one that was waiting for room
    in the queue (no caller waits for a writer that has ended).

    A write that fails (disk full, a message that does not fit its topic's type) ends the
    recording: its one-line reason is kept in :attr:`error` and handed once to ``on_error``, from
    the writer thread; later messages are dropped and the bag is still closed at :meth:`close`
    with what was written. A bag that cannot be closed keeps its reason in :attr:`close_error`
    instead, not handed to ``on_error``: the caller of :meth:`close` reports it.

    At most ``max_queued`` messages wait: a writer that falls that far behind (a simulation running
    as fast as possible, ``real_time_factor:=0`` or lock-step) makes :meth:`write` wait for it, so
    the recording throttles the caller as it did when written in line, instead of filling memory.
    """

    def __init__(self, recorder: Recorder, on_error=None, max_queued: int = MAX_QUEUED):
        if max_queued < 1:
            raise ValueError(f'max_queued must be >= 1, got {max_queued}')
        self.recorder = recorder
        self.path = recorder.path
        self.on_error = on_error
        self.error: str | None = None          # the write that ended the recording
        self.close_error: str | None = None    # why the bag could not be closed
        self._items: collections.deque = collections.deque()
        self._max = max_queued
        self._closed = False
        self._ended = False                    # the writer thread has returned (closed, or died)
        lock = threading.Lock()
        self._not_empty = threading.Condition(lock)     # the writer waits for work
        self._not_full = threading.Condition(lock)      # callers wait for room
        self._thread = threading.Thread(target=self._run, name='recorder', daemon=True)
        self._thread.start()

    @property
    def count(self) -> int:
        """Messages written so far (those still queued not counted)."""
        return self.recorder.count

    def _take(self) -> list:
        """Everything queued, in order (waits for some); empty once closed and drained."""
        with self._not_empty:
            while not self._items and not self._closed:
                self._not_empty.wait()
            batch = list(self._items)
            self._items.clear()
            self._not_full.notify_all()
            return batch

    def _run(self) -> None:
        try:
            self._write_batches()
        finally:                                    # callers never wait for a writer that has ended
            with self._not_full:
                self._ended = True
                self._not_full.notify_all()

    def _write_batches(self) -> None:
        rec = self.recorder
        while True:
            batch = self._take()
            if not batch:
                return
            for item in batch:
                if self.error is not None:
                    break
                self.error = _write_queued(rec, item)
                if self.error is not None:
                    self._report(self.error)

    def close(self) -> None:
        """Write everything enqueued so far, then close the bag (idempotent)."""
        if not self._end_queue():
            return
        self._thread.join()
        try:
            self.recorder.close()
        except Exception as exc:                   # noqa: BLE001 - the caller reports it in its closing line
            self.close_error = one_line(exc)

    def __enter__(self) -> 'RecorderThread':
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def one_line(exc: BaseException) -> str:
    """An exception as one line of text: the first line of its message, after its type unless it
    is one whose message says it all (a bad value, the file system, the bag)."""
    text = str(exc).strip()
    if not text:
        return type(exc).__name__
    first = text.splitlines()[0]
    return first if isinstance(exc, (ValueError, OSError, BagError)) else f'{type(exc).__name__}: {first}'
