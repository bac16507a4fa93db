"""The whole walk replayed: the recorded goals through the MuJoCo hexapod on the walk's ground.

The free-leg model (:mod:`.simulate`) holds only while a leg swings. Stance, touchdown, lift-off and
leveling are where the legs carry the body, so they need the whole robot: the trunk on its legs, the
feet on the ground, every servo's firmware. This module replays every recorded goal write, at the
firmware tick it acts on, through :class:`hexapod_sim.physics.plant.HexapodSim` on the ground the walk
was recorded on (a :class:`~hexapod_sim.physics.terrain.Ground`: the terrain's name, its seed and where
the robot started; a calibration walk of a real robot is on a flat floor) and predicts every recorded
read from the replay's output-shaft angles (a readout delay of the description shifts the sample time,
as the servo would). The replay is open loop: where it matches the recording it stays in step with it;
where physics the replay leaves out moves the trunk (a foot that lands a block's edge away), the two
part, and from then on every joint differs.

How the replay is judged against the recording, phase by phase, and what the whole walk finds beyond the
swings is :mod:`.whole_walk_search`'s.
"""
from __future__ import annotations

import bisect
import math

import numpy as np

from hexapod_model.description import Robot
from hexapod_model.joints import JOINTS, Joint
from hexapod_model.servo import theta_to_tick
from hexapod_sim.discrepancy.recording import Recording, RecordingError
from hexapod_sim.physics.terrain import Ground, TerrainError, make_terrain
from hexapod_sim.physics.write_schedule import WriteSchedule, can_replay, replay_writes


def sorted_writes(rec: Recording, dt: float) -> list[tuple[int, dict[str, float]]]:
    """:meth:`~.recording.Recording.writes_by_tick` as (tick, goals) in tick order."""
    writes = rec.writes_by_tick(dt)
    return [(k, writes[k]) for k in sorted(writes)]


class ReplayInputs:
    """What every replay of one recording on one ground shares, made once: the recorded writes by tick
    (:func:`sorted_writes`), the same as a :class:`~hexapod_sim.physics.write_schedule.WriteSchedule` for
    the compiled loop, and the ground's terrain; and :attr:`replayed_s`, the physics time [s] the replays
    that share them have run together (what a search has cost, counted in the walk's own time)."""

    def __init__(self, rec: Recording, ground: Ground):
        self.rec, self.ground = rec, ground
        self.replayed_s = 0.0
        self._writes: dict[float, list] = {}          # physics step -> the writes by tick
        self._schedules: dict[float, WriteSchedule | None] = {}
        self._terrain = None

    def writes(self, dt: float) -> list:
        if dt not in self._writes:
            self._writes[dt] = sorted_writes(self.rec, dt)
        return self._writes[dt]

    def schedule(self, dt: float) -> WriteSchedule | None:
        """The writes as a schedule (None: a joint name or an angle the sim refuses; the Python loop says so)."""
        if dt not in self._schedules:
            self._schedules[dt] = WriteSchedule.of(self.writes(dt))
        return self._schedules[dt]

    def terrain(self):
        """The ground's terrain (None where its name or seed is bad: the replay reports it)."""
        if self._terrain is None:
            try:
                self._terrain = make_terrain(self.ground.terrain, self.ground.seed)
            except TerrainError:
                return None
        return self._terrain


def _start_angles(rec: Recording, sim) -> dict[str, float] | None:
    """The recording's first read of every joint by name, unless they are the plant's home pose (then None:
    a recording of the sim from its start replays from exactly the state it was made from)."""
    home = sim.true_joint_angles()
    first = {j: float(s.theta_rad[0]) for j, s in rec.states.items() if len(s)}
    tick = sim.robot.servo
    off = max((abs(float(theta_to_tick(v, tick) - theta_to_tick(home[JOINTS.index(j)], tick)))
               for j, v in first.items()), default=0.0)
    return None if off <= 1.0 else {str(j): v for j, v in first.items()}


class WalkReplay:
    """One open-loop replay of the recorded goals through the MuJoCo hexapod of ``robot`` (effects included)
    on ``ground``, advanced on demand (:meth:`run_to`) so a caller can stop it once it has what it needs.

    The compiled loop runs from one goal write to the next and keeps the output angle of every physics
    step (:meth:`HexapodSim.keep_output_angles`); :attr:`pred` holds the predicted ticks at every recorded
    read of ``joints`` up to ``t_end_s``, NaN for the reads not yet replayed. ``inputs``: the
    :class:`ReplayInputs` of ``rec`` on ``ground`` (:class:`.whole_walk_search.Replays` shares one between
    its replays; default: made here). The writes run in the compiled loop
    (:func:`~hexapod_sim.physics.write_schedule.replay_writes`) where the sim allows it."""

    def __init__(self, rec: Recording, robot: Robot, ground: Ground, joints=None, t_end_s: float | None = None,
                 inputs: ReplayInputs | None = None):
        from hexapod_sim.physics.plant import HexapodSim, SimError
        inputs = inputs or ReplayInputs(rec, ground)
        terrain = inputs.terrain()
        self.rec = rec
        self.joints = [j for j in (joints or rec.states) if j in rec.states]
        try:
            sim = HexapodSim(robot, terrain=ground.terrain if terrain is None else terrain, seed=ground.seed,
                             imu_rate_hz=0.0, start_xy_m=ground.start_xy_m)
        except SimError as exc:
            raise RecordingError(f'whole-walk replay: {exc}') from None
        sim.reset()
        start = _start_angles(rec, sim)
        if start is not None:
            sim.reset(joint_angles=start)
        self.sim, self.dt, self.servo, self._inputs = sim, sim.dt, robot.servo, inputs
        self.t_end = rec.duration_s if t_end_s is None else min(t_end_s, rec.duration_s)
        self.n = n = int(math.ceil(self.t_end / self.dt)) + 2
        self.grid = sim.keep_output_angles(n)
        writes = inputs.writes(self.dt)
        self._writes = writes[:bisect.bisect_left(writes, n, key=lambda w: w[0])]
        self._schedule = inputs.schedule(self.dt) if can_replay(sim) else None
        self._next_write = 0
        self.steps = 0                          # physics steps run: grid rows 0 .. steps - 1 are filled
        self._cols = {j: JOINTS.index(j) for j in self.joints}
        self._i0, self._f, self.pred, self._done = {}, {}, {}, {}
        for j in self.joints:
            t = rec.states[j].t_s
            t = t[t <= self.t_end]
            delay = robot.joint_effects(j).readout_delay_s
            x = np.clip((t - delay) / self.dt, 0.0, n - 1.0)
            i0 = np.minimum(np.floor(x).astype(np.int64), n - 2)
            self._i0[j], self._f[j] = i0, x - i0
            self.pred[j] = np.full(len(t), np.nan)
            self._done[j] = 0

    def run_to(self, t_s: float) -> float:
        """Replay until every read at or before ``t_s`` (and ``t_end_s``) is predicted; -> the time [s] up
        to which every read is."""
        target = min(self.n, int(math.ceil(min(t_s, self.t_end) / self.dt)) + 2)
        sim, w = self.sim, self._writes
        self._inputs.replayed_s += max(target - self.steps, 0) * self.dt
        if self._schedule is not None and self.steps < target:     # the same loop, compiled
            self._next_write = replay_writes(sim, self._schedule, target, self._next_write)
            self.steps = target
        while self.steps < target:
            if self._next_write < len(w) and w[self._next_write][0] <= self.steps:
                sim.sync_write(w[self._next_write][1])
                self._next_write += 1
                continue
            stop = w[self._next_write][0] if self._next_write < len(w) else target
            sim.step((min(stop, target) - self.steps) * self.dt)
            self.steps = min(stop, target)
        for j in self.joints:                   # the reads whose two grid rows are filled
            i0, k0 = self._i0[j], self._done[j]
            k1 = int(np.searchsorted(i0, self.steps - 2, side='right'))
            if k1 > k0:
                g, f = self.grid[:, self._cols[j]], self._f[j][k0:k1]
                self.pred[j][k0:k1] = theta_to_tick(g[i0[k0:k1]] * (1.0 - f) + g[i0[k0:k1] + 1] * f, self.servo)
                self._done[j] = k1
        return self.covered_s()

    def covered_s(self) -> float:
        """Every read before this time [s] is predicted (the end of the walk once the replay is done)."""
        if self.steps >= self.n:
            return math.inf
        return min((float(self.rec.states[j].t_s[k]) for j, k in self._done.items() if k < len(self.pred[j])),
                   default=math.inf)

    @property
    def finished(self) -> bool:
        return self.steps >= self.n


def replay_walk(rec: Recording, robot: Robot, ground: Ground, joints=None,
                t_end_s: float | None = None) -> dict[str, np.ndarray]:
    """Predicted ticks at every recorded read of ``joints`` (default all recorded) up to ``t_end_s``:
    the recorded goals through the MuJoCo hexapod of ``robot`` (effects included) on ``ground``."""
    r = WalkReplay(rec, robot, ground, joints, t_end_s)
    r.run_to(math.inf)
    return r.pred


def rec_ticks(rec: Recording, robot: Robot, joint: Joint) -> np.ndarray:
    """The recorded reads of ``joint`` in ticks."""
    return theta_to_tick(rec.states[joint].theta_rad, robot.servo)


__all__ = ['ReplayInputs', 'WalkReplay', 'rec_ticks', 'replay_walk', 'sorted_writes']
