"""The one bag loader: what a contract bag holds, topic by topic, as typed series.

:func:`load_bag` opens a rosbag2 directory or ``.mcap`` file once, checks the contract topics it is
asked for (present where required, recorded with the contract's type) and reads them in one pass
into a :class:`BagContents`. The offline tools build their own views from it: ``./hexapod analyse``
(:mod:`hexapod_locomotion.trials.analyse`) and the discrepancy tool's
:class:`~hexapod_sim.discrepancy.recording.Recording`.

Every problem is a :class:`~hexapod_sim.bagio.common.BagError` whose message starts with the bag's
path and fits on one line; the reader's warnings about a damaged bag are emitted as it reads and
kept in :attr:`BagContents.warnings`.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterable, Mapping

import numpy as np

from hexapod_model import contract
from hexapod_model.imu import ImuSeries
from hexapod_model.joints import Joint, JointNameError
from hexapod_sim.bagio.common import BagError
from hexapod_sim.bagio.reader import BagReader

# the topics the loader knows, in the order they are read
TOPICS = (contract.SWING_DOWN, contract.JOINT_STATES, contract.JOINT_COMMANDS, contract.GROUND_DETECTION,
          contract.POWER, contract.SIM_TRUTH_POSE, contract.IMU, contract.SIM_SCENE)


@dataclass(frozen=True)
class JointMessages:
    """A ``sensor_msgs/msg/JointState`` topic message by message, in log order: the header stamp [s]
    and exactly [ns], the log (record) time [ns], the joint names and their positions [rad]."""

    stamp_s: tuple[float, ...] = ()
    stamp_ns: tuple[int, ...] = ()
    log_ns: tuple[int, ...] = ()
    name: tuple[tuple[str, ...], ...] = ()
    position: tuple[tuple[float, ...], ...] = ()

    def __len__(self) -> int:
        return len(self.stamp_s)

    def per_joint(self, log_time: bool = False) -> dict[Joint, np.ndarray]:
        """``{joint: array (N, 2)}`` with columns (header.stamp [s], position [rad]), sorted by stamp
        (stable); ``log_time=True`` adds a third column, the log time [s], so a stamp that disagrees
        with when the message was recorded can be found. A name that is no joint of the contract is a
        :class:`BagError`."""
        acc: dict[str, list] = {}
        for stamp, t_ns, names, pos in zip(self.stamp_s, self.log_ns, self.name, self.position):
            for n, p in zip(names, pos):
                acc.setdefault(n, []).append((stamp, p, t_ns * 1e-9) if log_time else (stamp, p))
        out = {}
        for n, rows in acc.items():
            try:
                joint = Joint.parse(n)
            except JointNameError as exc:
                raise BagError(f'a JointState message names an unknown joint: {exc}') from None
            a = np.asarray(rows, dtype=float).reshape(-1, 3 if log_time else 2)
            out[joint] = a[np.argsort(a[:, 0], kind='stable')]
        return out


@dataclass(frozen=True)
class Detection:
    """One ``/ground_detection`` message: the controller's decision on one read of one leg."""

    t_s: float                  # stamp of the read it decided on [s]
    t_ns: int                   # the same stamp exactly [ns]
    swing_start_s: float        # the swing-down it belongs to (its ``/swing_down`` stamp) [s]
    leg: int
    stopped: bool
    stop_reason: int


@dataclass(frozen=True)
class SwingDown:
    """One ``/swing_down`` message: the stamp [s] and the decoded message (Algorithm 1's inputs)."""

    t_s: float
    msg: object


@dataclass(frozen=True)
class TimeSeries:
    """Stamped samples: ``t_s`` (N,) [s] and ``values`` (N,) or (N, k)."""

    t_s: np.ndarray
    values: np.ndarray

    def __len__(self) -> int:
        return len(self.t_s)


def _empty(k: int = 0) -> TimeSeries:
    return TimeSeries(np.zeros(0), np.zeros((0, k)) if k else np.zeros(0))


@dataclass(frozen=True)
class BagContents:
    """The contract topics of one bag (see the module docstring); a topic not in the bag, or not
    asked for, is empty (``scene`` None)."""

    path: str
    swing_downs: tuple[SwingDown, ...] = ()
    joint_states: JointMessages = field(default_factory=JointMessages)
    joint_commands: JointMessages = field(default_factory=JointMessages)
    detections: tuple[Detection, ...] = ()
    power: TimeSeries = field(default_factory=_empty)         # |voltage x current| [W] of /power
    truth_pose: TimeSeries = field(default_factory=lambda: _empty(3))   # /sim/body_pose position (N, 3) [m]
    imu: ImuSeries = field(default_factory=ImuSeries.empty)   # /imu as recorded, in log order
    scene: str | None = None                                  # the first /sim/scene text
    topics: frozenset = frozenset()                           # the contract topics the bag has
    warnings: tuple[str, ...] = ()                            # what the reader found damaged
    lost_spans: tuple[tuple[int, int], ...] = ()              # log time [ns] of corrupt chunks (BagReader.lost_spans)


def _ns(stamp) -> int:
    return int(stamp.sec) * contract.NS_PER_S + int(stamp.nanosec)


def _check(reader: BagReader, path: str, wanted: Iterable[str], required: Mapping[str, str]) -> list[str]:
    """The wanted topics the bag has; a BagError for a required one it lacks or one of another type."""
    in_bag = {contract.topic_key(t): t for t in reader.topics()}   # bags store '/swing_down'; the contract: 'swing_down'
    for topic, why in required.items():
        if contract.topic_key(topic) not in in_bag:
            raise BagError(f'{path}: no {contract.bag_topic(topic)} topic - {why}')
    present = [t for t in wanted if t in in_bag]
    for t in present:                   # a topic of another type would be read field by field
        msg_type = reader.topics()[in_bag[t]]
        if msg_type != contract.MSG_TYPES[t]:
            raise BagError(f'{path}: {in_bag[t]} is recorded as {msg_type or "an unknown type"}, expected '
                           f'{contract.MSG_TYPES[t]}')
    return present


class _Acc:
    """Rows per topic while the bag is read."""

    def __init__(self):
        self.joints = {contract.JOINT_STATES: ([], [], [], [], []), contract.JOINT_COMMANDS: ([], [], [], [], [])}
        self.swings, self.detections, self.power, self.pose, self.imu = [], [], [], [], []
        self.scene = None

    def add(self, topic: str, t_ns: int, msg) -> None:
        if topic in self.joints:
            names, pos = tuple(msg.name), tuple(float(p) for p in msg.position)
            if len(pos) < len(names):
                raise BagError(f'{contract.bag_topic(topic)} message at t={t_ns} ns names {len(names)} joint(s) but '
                               f'has {len(pos)} position(s)')
            cols = self.joints[topic]
            for col, v in zip(cols, (contract.stamp_seconds(msg.header.stamp), _ns(msg.header.stamp), t_ns,
                                     names, pos)):
                col.append(v)
        elif topic == contract.SWING_DOWN:
            self.swings.append(SwingDown(contract.stamp_seconds(msg.header.stamp), msg))
        elif topic == contract.GROUND_DETECTION:
            self.detections.append(Detection(contract.stamp_seconds(msg.header.stamp), _ns(msg.header.stamp),
                                             contract.stamp_seconds(msg.swing_start), int(msg.leg),
                                             bool(msg.stopped), int(msg.stop_reason)))
        elif topic == contract.POWER:
            self.power.append((contract.stamp_seconds(msg.header.stamp), abs(msg.voltage * msg.current)))
        elif topic == contract.SIM_TRUTH_POSE:
            p = msg.pose.position
            self.pose.append((contract.stamp_seconds(msg.header.stamp), p.x, p.y, p.z))
        elif topic == contract.IMU:
            q, a, w = msg.orientation, msg.linear_acceleration, msg.angular_velocity
            self.imu.append((contract.stamp_seconds(msg.header.stamp), a.x, a.y, a.z, w.x, w.y, w.z,
                             q.w, q.x, q.y, q.z))
        elif topic == contract.SIM_SCENE and self.scene is None:
            self.scene = str(msg.data)

    def contents(self, path: str, topics: frozenset, warnings: list, lost_spans=()) -> BagContents:
        power = np.asarray(self.power, dtype=float).reshape(-1, 2)
        pose = np.asarray(self.pose, dtype=float).reshape(-1, 4)
        imu = np.asarray(self.imu, dtype=float).reshape(-1, 11)
        return BagContents(
            path=path, swing_downs=tuple(self.swings),
            joint_states=JointMessages(*(tuple(c) for c in self.joints[contract.JOINT_STATES])),
            joint_commands=JointMessages(*(tuple(c) for c in self.joints[contract.JOINT_COMMANDS])),
            detections=tuple(self.detections),
            power=TimeSeries(power[:, 0].copy(), power[:, 1].copy()),
            truth_pose=TimeSeries(pose[:, 0].copy(), pose[:, 1:].copy()),
            imu=ImuSeries(imu[:, 0].copy(), imu[:, 1:4].copy(), imu[:, 4:7].copy(), imu[:, 7:11].copy()),
            scene=self.scene, topics=topics, warnings=tuple(warnings), lost_spans=tuple(lost_spans))


def load_bag(path: str | Path, topics: Iterable[str] = TOPICS, required: Mapping[str, str] | None = None
             ) -> BagContents:
    """Read ``topics`` (contract names, default all the loader knows) of the bag at ``path``.

    ``required`` maps a contract topic the caller cannot do without to why it is needed: a bag
    without it is a :class:`BagError` saying ``no /TOPIC topic - WHY``. So is a missing path, a
    bag nothing is readable in, a read topic recorded with another type than the contract's, and a
    JointState message with fewer positions than names.
    """
    p = Path(path)
    if not p.exists():
        raise BagError(f'{p}: no such bag (expected a rosbag2 directory or a .mcap file)')
    reader = BagReader(str(p))
    wanted = [contract.topic_key(t) for t in topics]
    unknown = sorted(set(wanted) - set(TOPICS))
    if unknown:
        raise ValueError(f'load_bag: no series for the topic(s) {unknown}; it reads {list(TOPICS)}')
    present = _check(reader, str(path), wanted, required or {})
    acc = _Acc()
    for bag_name, msg_type, t_ns, msg in reader.messages(topics=present) if present else ():
        try:
            acc.add(contract.topic_key(bag_name), t_ns, msg)
        except BagError as exc:
            raise BagError(f'{path}: {exc}') from None
        except (AttributeError, TypeError, ValueError) as exc:     # e.g. a damaged schema record that still parses
            raise BagError(f'{path}: {bag_name} message at t={t_ns} ns does not read as the contract\'s {msg_type} '
                           f'({exc}): the definition the bag stores for {msg_type} is not the installed one') from None
    in_bag = frozenset(contract.topic_key(t) for t in reader.topics())
    return acc.contents(str(path), in_bag, reader.warnings, reader.lost_spans)


__all__ = ['BagContents', 'Detection', 'JointMessages', 'SwingDown', 'TimeSeries', 'TOPICS', 'load_bag']
