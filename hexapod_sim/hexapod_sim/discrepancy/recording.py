"""What the discrepancy tool reads: the goal writes and position reads of a recording.

A :class:`Recording` holds, per joint, the stamps and goal angles of every bus write that
included the joint (``/joint_commands``) and the stamps and angles of every position read
(``/joint_states``), as the recording contract defines them (:mod:`hexapod_model.contract`):
DH joint angles ``theta`` in radians, a write's stamp is the time of the write, a read's stamp is
the time the position was sampled. Times are seconds since ``t0_ns`` (the earliest stamp floored
to a whole millisecond, so the 1 kHz firmware grid of the sim stays aligned).

:func:`load_recording` builds one from a rosbag2 directory or a single ``.mcap`` file read by
:func:`hexapod_sim.bagio.load_bag`; :meth:`Recording.write_bag` writes one back (tests, benchmark).
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path
from typing import Iterable, Mapping

import numpy as np

from hexapod_model.contract import JOINT_COMMANDS, JOINT_STATES, MSG_TYPES, bag_topic, stamp_parts_ns
from hexapod_model.imu import ImuSeries
from hexapod_model.joints import JOINTS, Joint, JointNameError

IMU_MIN_SPECIFIC_FORCE = 1.0     # [m/s^2]: /imu samples below are left out (see load_recording)


class RecordingError(ValueError):
    """The recording cannot be analysed; the message says what is wrong with it."""


@dataclass(frozen=True)
class Series:
    """Stamped samples of one joint: ``t_s`` ascending [s], ``theta_rad`` the DH angle [rad]."""

    t_s: np.ndarray
    theta_rad: np.ndarray

    def __post_init__(self):
        if self.t_s.shape != self.theta_rad.shape or self.t_s.ndim != 1:
            raise RecordingError(f'series stamps {self.t_s.shape} and values {self.theta_rad.shape} differ in shape')

    def __len__(self) -> int:
        return len(self.t_s)


@dataclass(frozen=True)
class Recording:
    """Goal writes and position reads per joint (see the module docstring)."""

    commands: Mapping[Joint, Series]
    states: Mapping[Joint, Series]
    t0_ns: int = 0
    source: str = '<memory>'
    glitches: tuple = ()     # samples left out as physically impossible (glitches.Glitch)
    # /imu where the recording has one, stamped on the same clock as the reads; the walk replay takes
    # the body's motion from its specific force and angular velocity (body_motion.py)
    imu: ImuSeries | None = None
    # what a simulated robot walked on (hexapod_sim.physics.terrain.Ground), from the bag's /sim/scene
    ground: object | None = None
    # (start_s, end_s) spans whose messages a damaged bag lost (corrupt chunks skipped by the reader): no goal
    # and no read is known there, so nothing may be replayed across one
    lost: tuple = ()

    @property
    def joints(self) -> tuple[Joint, ...]:
        """Joints that were both commanded and read, in the contract's order."""
        return tuple(j for j in JOINTS if j in self.commands and j in self.states and len(self.states[j]))

    @property
    def duration_s(self) -> float:
        ends = [s.t_s[-1] for s in list(self.commands.values()) + list(self.states.values()) if len(s)]
        return float(max(ends)) if ends else 0.0

    @property
    def lost_s(self) -> float:
        """The time the lost spans cover [s]."""
        return float(sum(b - a for a, b in self.lost))

    def writes_by_tick(self, dt: float) -> dict[int, dict[str, float]]:
        """The recorded goal writes by the firmware tick (period ``dt`` [s]) they act on, the first at or
        after the write, with the joints' names (a plant's goals)."""
        writes: dict[int, dict[str, float]] = {}
        for j, cmd in self.commands.items():
            name = str(j)
            ks = np.ceil(cmd.t_s / dt - 1e-9).astype(np.int64)
            for k, th in zip(ks.tolist(), cmd.theta_rad.tolist()):
                writes.setdefault(k, {})[name] = th
        return writes

    def before(self, t_end_s: float) -> 'Recording':
        """This recording up to ``t_end_s`` [s] (the samples before it), without lost spans after it."""
        def cut(d):
            return {j: Series(s.t_s[s.t_s < t_end_s], s.theta_rad[s.t_s < t_end_s]) for j, s in d.items()}
        imu = None if self.imu is None else self.imu.take(self.imu.t_s < t_end_s)
        return replace(self, commands=cut(self.commands), states=cut(self.states), imu=imu,
                       glitches=tuple(g for g in self.glitches if g.t_s < t_end_s),
                       lost=tuple((a, b) for a, b in self.lost if b <= t_end_s))

    @classmethod
    def from_samples(cls, commands: Iterable[tuple[float, Mapping[Joint | str, float]]],
                     reads: Iterable[tuple[float, Joint | str, float]], source: str = '<memory>',
                     t0_ns: int = 0) -> 'Recording':
        """Build from ``commands = [(t_s, {joint: goal_rad})]`` and ``reads = [(t_s, joint, theta_rad)]``
        (joints or their names)."""
        cmd: dict[Joint | str, list] = {}
        for t, goals in commands:
            for j, v in goals.items():
                cmd.setdefault(j, []).append((float(t), float(v)))
        st: dict[Joint | str, list] = {}
        for t, j, v in reads:
            st.setdefault(j, []).append((float(t), float(v)))
        return cls(commands=_to_series(cmd, 'command'), states=_to_series(st, 'read'), t0_ns=t0_ns, source=source)

    def write_bag(self, path: str | Path) -> None:
        """Write this recording as a contract bag (``/joint_commands`` per write, ``/joint_states`` per read)."""
        from hexapod_sim.bagio import BagWriter  # only needed when bags are written
        events = []
        writes: dict[float, dict[Joint, float]] = {}
        for j, s in self.commands.items():
            for t, v in zip(s.t_s, s.theta_rad):
                writes.setdefault(float(t), {})[j] = float(v)
        for t, goals in writes.items():
            joints = [j for j in JOINTS if j in goals]
            events.append((t, 0, JOINT_COMMANDS, [str(j) for j in joints], [goals[j] for j in joints]))
        for j, s in self.states.items():
            for t, v in zip(s.t_s, s.theta_rad):
                events.append((float(t), 1, JOINT_STATES, [str(j)], [float(v)]))
        events.sort(key=lambda e: (e[0], e[1]))
        writer = BagWriter(str(path), flush_period_s=60.0)   # written in one go: large chunks compress better
        try:
            for t, _, topic, names, values in events:
                t_ns = self.t0_ns + int(round(t * 1e9))
                sec, nanosec = stamp_parts_ns(t_ns)
                msg = {'header': {'stamp': {'sec': sec, 'nanosec': nanosec}, 'frame_id': ''},
                       'name': names, 'position': values, 'velocity': [], 'effort': []}
                writer.write(topic, MSG_TYPES[topic], msg, t_ns)
        finally:
            writer.close()


def _to_series(d: Mapping[Joint | str, list], what: str) -> dict[Joint, Series]:
    out = {}
    for j, rows in d.items():
        try:
            j = Joint.of(j)
        except JointNameError as exc:
            raise RecordingError(f'{what} for unknown joint: {exc}') from None
        a = np.array(rows, dtype=float).reshape(-1, 2)
        if not np.all(np.isfinite(a)):
            bad = int(np.count_nonzero(~np.isfinite(a).all(axis=1)))
            raise RecordingError(f'{what}s of {j}: {bad} sample(s) are NaN or infinite')
        order = np.argsort(a[:, 0], kind='stable')
        a = a[order]
        out[j] = Series(a[:, 0].copy(), a[:, 1].copy())
    return out


# ----------------------------------------------------------------------------- bag loading
IMU_COVER_S = 1.0      # /imu must start and end within this of the joint reads, or it is not used


def screen_imu(imu: ImuSeries, t0_s: float, duration_s: float) -> tuple[ImuSeries | None, tuple]:
    """``/imu`` samples on the recording's clock (``t0_s`` taken off), or None with a
    :class:`~.glitches.Glitch` saying why it is not used: stamps that do not cover the joint reads
    (another clock: a bag whose /imu is stamped in wall time and its reads in sim time). Samples with
    a non-finite value are dropped and the rest sorted by stamp; those with (almost) no specific force
    are left out silently: a trunk on its legs feels about g, and the sim's sample before its first
    physics step, or a dropout, would replay the legs weightless."""
    from hexapod_sim.discrepancy.glitches import Glitch
    imu = imu.take(imu.finite())
    if len(imu) < 2:
        return None, ()
    imu = imu.take(np.argsort(imu.t_s, kind='stable'))
    imu = imu.take(np.linalg.norm(imu.accel, axis=1) >= IMU_MIN_SPECIFIC_FORCE)
    if len(imu) < 2:
        return None, ()
    imu = imu.shifted(t0_s)
    a, b = float(imu.t_s[0]), float(imu.t_s[-1])
    if a > IMU_COVER_S or b < duration_s - IMU_COVER_S:
        return None, (Glitch('imu', None, max(a, 0.0), 'clock',
                             f'/imu stamped {a:.1f} to {b:.1f} s, the joint reads 0 to {duration_s:.1f} s: '
                             'another clock, /imu not used'),)
    return imu, ()


def _ground(scene: str | None, p: Path):
    """The ground of the bag's ``/sim/scene`` (a recording of the sim), None if it has none."""
    from hexapod_sim.physics.terrain import Ground, TerrainError
    if scene is None:
        return None
    try:
        return Ground.from_text(scene)
    except TerrainError as exc:
        raise RecordingError(f'{p}: /sim/scene: {exc}') from None


def load_recording(path: str | Path, robot=None) -> Recording:
    """Read ``/joint_commands`` and ``/joint_states`` from a rosbag2 directory or an ``.mcap`` file.

    Samples that cannot be physical (:mod:`.glitches`: stamps far from their record time or out of
    order, positions out of range or beyond the servo's speed from their neighbours; the servo of
    ``robot``, default the packaged description) are left out and listed in ``Recording.glitches``.
    """
    from hexapod_sim.discrepancy.glitches import Glitch, screen
    if robot is None:
        from hexapod_model.description import load_robot
        robot = load_robot()
    p = Path(path)
    from hexapod_model import contract
    from hexapod_sim.bagio import BagError, load_bag
    try:
        bag = load_bag(p, topics=(JOINT_COMMANDS, JOINT_STATES, contract.IMU, contract.SIM_SCENE),
                       required={JOINT_COMMANDS: 'the tool replays the recorded goals',
                                 JOINT_STATES: 'nothing to compare the model with'})
        series = {JOINT_COMMANDS: bag.joint_commands.per_joint(log_time=True),
                  JOINT_STATES: bag.joint_states.per_joint(log_time=True)}
    except BagError as exc:
        raise RecordingError(str(exc) if str(exc).startswith(str(p)) else f'{p}: {exc}') from None   # named once
    ground = _ground(bag.scene, p)
    for topic, d in series.items():
        for j, a in d.items():
            if not np.all(np.isfinite(a[:, :2])):
                what = 'command' if topic == JOINT_COMMANDS else 'read'
                bad = int(np.count_nonzero(~np.isfinite(a[:, :2]).all(axis=1)))
                raise RecordingError(f'{p}: {what}s of {j}: {bad} sample(s) are NaN or infinite')
    cmds, bad_c = screen(series[JOINT_COMMANDS], 'command', None)
    reads, bad_r = screen(series[JOINT_STATES], 'read', robot.servo)
    cmds = {j: a for j, a in cmds.items() if len(a)}
    reads = {j: a for j, a in reads.items() if len(a)}
    if not cmds:
        raise RecordingError(f'{p}: no {bag_topic(JOINT_COMMANDS)} messages (the tool replays the recorded goals)')
    if not reads:
        raise RecordingError(f'{p}: no {bag_topic(JOINT_STATES)} messages (nothing to compare the model with)')
    t_first = min(float(a[0, 0]) for d in (cmds, reads) for a in d.values() if len(a))
    t0_ms = int(np.floor(t_first * 1000.0 + 1e-6))
    t0 = t0_ms / 1000.0

    def conv(d, what):
        out = {}
        for j, a in d.items():
            out[j] = [(float(t) - t0, float(v)) for t, v in a]
        return _to_series(out, what)
    duration = max(float(a[-1, 0]) for d in (cmds, reads) for a in d.values() if len(a)) - t0
    imu, imu_glitches = screen_imu(bag.imu, t0, duration)
    glitches = tuple(sorted((Glitch(topic, j, t - t0, kind, detail)
                             for topic, found in (('command', bad_c), ('read', bad_r))
                             for j, t, kind, detail in found), key=lambda g: (g.t_s, g.joint))) + imu_glitches
    lost = tuple((max(a / 1e9 - t0, 0.0), min(b / 1e9 - t0, duration)) for a, b in bag.lost_spans
                 if b / 1e9 - t0 > 0.0 and a / 1e9 - t0 < duration)
    return Recording(commands=conv(cmds, 'command'), states=conv(reads, 'read'), t0_ns=t0_ms * 1_000_000,
                     source=str(p), glitches=glitches, imu=imu, ground=ground, lost=lost)
