"""The whole walk: the recorded goals replayed through the MuJoCo hexapod on the walk's ground.

The free-leg model (:mod:`.simulate`) holds only while a leg swings. Stance, touchdown, lift-off and
leveling are where the legs carry the body, so they need the whole robot: the trunk on its legs, the
feet on the ground, every servo's firmware. This module replays every recorded goal write, at the
firmware tick it acts on, through :class:`hexapod_sim.physics.plant.HexapodSim` on the ground the walk
was recorded on (a :class:`Ground`: the terrain's name, its seed and where the robot started; a
calibration walk of a real robot is on a flat floor) and predicts every recorded read from the
replay's output-shaft angles (a readout delay of the description shifts the sample time, as the servo
would). The replay is open loop: where it matches the recording it stays in step with it; where
physics the replay leaves out moves the trunk (a foot that lands a block's edge away), the two part,
and from then on every joint differs. :func:`in_step_until` finds that moment, and only reads before
it are judged.

Phases (:data:`WHOLE_PHASES`): the gait phases of :mod:`.segments`, with the first
``TOUCHDOWN_S`` of a stance after a swing-down (the leg takes its share of the body's weight) and
the first ``LIFT_OFF_S`` of a swing-up (it gives the share up) told apart.

What the whole walk finds beyond the swings (effects put on every joint, effects under load) is
:mod:`.whole_walk_search`'s.
"""
from __future__ import annotations

import bisect
import math
import warnings
from dataclasses import dataclass

import numpy as np

from hexapod_model.description import Robot
from hexapod_model.joints import JOINTS, Joint
from hexapod_model.servo import theta_to_tick
from hexapod_sim.discrepancy.recording import Recording, RecordingError
from hexapod_sim.discrepancy.segments import PHASES, LegPhases
from hexapod_sim.physics.terrain import Ground

WHOLE_PHASES = ('swing_up', 'swing_forward', 'swing_down', 'stance', 'touchdown', 'lift_off', 'leveling')
TOUCHDOWN_S = 0.1          # [s] of stance after a swing-down stops: the leg takes up the body's weight
LIFT_OFF_S = 0.1           # [s] of swing-up after it starts: the leg gives up its share
STEP_WINDOW_S = 0.5        # [s] windows in which the replay is judged in step with the recording
OUT_OF_STEP_TICKS = 1.0    # the median joint's RMS over a window above this: the trunk went elsewhere
START_S = 0.2              # [s] at the start left out (the first reads settle the pose)
LOADED_PHASES = ('stance', 'touchdown', 'lift_off', 'leveling')   # where the legs carry the body
ROUNDING_TICKS = 0.5       # a phase's RMS error at most this is tick rounding (uniform rounding: 0.29)


def whole_labels(phases: LegPhases, t: np.ndarray) -> np.ndarray:
    """Index into :data:`WHOLE_PHASES` for every time in ``t`` [s]."""
    t = np.asarray(t, dtype=float)
    out = phases.label(t)                       # PHASES indices; the first five names are the same
    assert WHOLE_PHASES[:3] == PHASES[:3] and PHASES[3] == 'stance' and PHASES[4] == 'leveling'
    out = np.where(out == PHASES.index('leveling'), WHOLE_PHASES.index('leveling'), out)
    for sw in phases.swings:
        out[(t >= sw.t_up) & (t < min(sw.t_up + LIFT_OFF_S, sw.t_forward))] = WHOLE_PHASES.index('lift_off')
        after = (t >= sw.t_stop) & (t < sw.t_stop + TOUCHDOWN_S) & (out == WHOLE_PHASES.index('stance'))
        out[after] = WHOLE_PHASES.index('touchdown')
    return out


def _writes_by_tick(rec: Recording, dt: float) -> dict[int, dict[str, float]]:
    """The recorded goal writes by the firmware tick they act on (the first at or after the write), with
    the joints' names (the plant's goals)."""
    writes: dict[int, dict[str, float]] = {}
    for j, cmd in rec.commands.items():
        name = str(j)
        ks = np.ceil(cmd.t_s / dt - 1e-9).astype(np.int64)
        for k, th in zip(ks.tolist(), cmd.theta_rad.tolist()):
            writes.setdefault(k, {})[name] = th
    return writes


def _sorted_writes(rec: Recording, dt: float) -> list[tuple[int, dict[str, float]]]:
    """:func:`_writes_by_tick` as (tick, goals) in tick order."""
    writes = _writes_by_tick(rec, dt)
    return [(k, writes[k]) for k in sorted(writes)]


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
    read of ``joints`` up to ``t_end_s``, NaN for the reads not yet replayed. ``writes``: ``(rec, dt) ->`` the
    recorded writes as (tick, goals) in tick order (default :func:`_sorted_writes`; :class:`Replays` makes
    them once)."""

    def __init__(self, rec: Recording, robot: Robot, ground: Ground, joints=None, t_end_s: float | None = None,
                 writes=None):
        from hexapod_sim.physics.plant import HexapodSim, SimError
        self.rec = rec
        self.joints = [j for j in (joints or rec.states) if j in rec.states]
        try:
            sim = HexapodSim(robot, terrain=ground.terrain, seed=ground.seed, imu_rate_hz=0.0,
                             start_xy_m=ground.start_xy_m)
        except SimError as exc:
            raise RecordingError(f'whole-walk replay: {exc}') from None
        sim.reset()
        start = _start_angles(rec, sim)
        if start is not None:
            sim.reset(joint_angles=start)
        self.sim, self.dt, self.servo = sim, sim.dt, robot.servo
        self.t_end = rec.duration_s if t_end_s is None else min(t_end_s, rec.duration_s)
        self.n = n = int(math.ceil(self.t_end / self.dt)) + 2
        self.grid = sim.keep_output_angles(n)
        writes = (writes or _sorted_writes)(rec, self.dt)
        self._writes = writes[:bisect.bisect_left(writes, n, key=lambda w: w[0])]
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


class Replays:
    """The whole-walk replays of one analysis (one recording, robot description and ground), each made once
    and run only as far as a caller needs: the nominal replay is compared against every set of effects
    tried, and the replay with the effects found is the search's starting point. A replay serves any span
    up to its own (the first steps of a longer replay are the shorter one's, write for write)."""

    def __init__(self, rec: Recording, robot: Robot, ground: Ground):
        self.rec, self.robot, self.ground = rec, robot, ground
        self._made: list[tuple[Robot, tuple, WalkReplay]] = []
        self._meas: dict[Joint, np.ndarray] = {}
        self._writes: dict[float, list] = {}          # physics step -> the writes by tick (the same for every model)

    def _sorted_writes(self, rec: Recording, dt: float) -> list:
        if dt not in self._writes:
            self._writes[dt] = _sorted_writes(rec, dt)
        return self._writes[dt]

    def meas(self, joint: Joint) -> np.ndarray:
        """The recorded reads of ``joint`` in ticks."""
        if joint not in self._meas:
            self._meas[joint] = rec_ticks(self.rec, self.robot, joint)
        return self._meas[joint]

    def get(self, model: Robot, joints, t_end_s: float | None = None, keep: bool = True) -> WalkReplay:
        """A replay of ``model`` that predicts ``joints`` up to ``t_end_s`` (None: the whole walk), not yet
        run further than before; ``keep``: hold it for later calls."""
        end = self.rec.duration_s if t_end_s is None else min(t_end_s, self.rec.duration_s)
        for m, js, r in self._made:
            if set(joints) <= set(js) and r.t_end >= end and m == model:
                return r
        r = WalkReplay(self.rec, model, self.ground, joints, t_end_s, self._sorted_writes)
        if keep:
            self._made.append((model, tuple(r.joints), r))
        return r

    def residuals(self, r: WalkReplay, joints=None, t_end_s: float | None = None) -> dict[Joint, np.ndarray]:
        """Recorded minus predicted ticks of ``joints`` (default the replay's) at the reads up to ``t_end_s``
        (default the replay's end); NaN where the replay has not yet come."""
        out = {}
        for j in (joints or r.joints):
            p = r.pred[j]
            if t_end_s is not None and t_end_s < r.t_end:
                p = p[:int(np.searchsorted(self.rec.states[j].t_s, t_end_s, side='right'))]
            out[j] = self.meas(j)[:len(p)] - p
        return out

    def in_step(self, model: Robot, joints, need_s: float = 0.0) -> tuple[dict[Joint, np.ndarray], float]:
        """(residuals, :func:`in_step_until`) of the whole-walk replay of ``model``, replayed until it leaves
        the recording (the first window whose median joint is above ``OUT_OF_STEP_TICKS``, as soon as every
        read of that window is replayed) but at least up to ``need_s``: the same verdict as the whole replay,
        and the same residuals before it."""
        r = self.get(model, joints)
        t = STEP_WINDOW_S
        while True:
            covered = r.run_to(t)
            res = self.residuals(r, joints)
            if r.finished:
                return res, in_step_until(self.rec, res)
            win = _window_rms(self.rec, res)
            done = int(np.count_nonzero((np.arange(len(win)) + 1) * STEP_WINDOW_S < covered))
            bad = np.flatnonzero(win[:done] > OUT_OF_STEP_TICKS)
            if len(bad) and covered >= need_s:
                return res, float(bad[0] * STEP_WINDOW_S)
            t = max(t, covered) + STEP_WINDOW_S


def _window_rms(rec: Recording, res: dict[str, np.ndarray]) -> np.ndarray:
    """The median joint's RMS residual [ticks] in every ``STEP_WINDOW_S`` window of the walk (NaN where no
    joint has a read with a residual)."""
    end = rec.duration_s
    n_win = int(math.ceil(end / STEP_WINDOW_S))
    per = np.full((len(res), n_win), np.nan)
    for r, (j, v) in enumerate(res.items()):
        t = rec.states[j].t_s[:len(v)]
        w = np.minimum((t / STEP_WINDOW_S).astype(np.int64), n_win - 1)
        sq = np.bincount(w, weights=v ** 2, minlength=n_win)
        cnt = np.bincount(w, minlength=n_win)
        with np.errstate(invalid='ignore', divide='ignore'):
            per[r] = np.sqrt(sq / cnt)
    with np.errstate(all='ignore'), warnings.catch_warnings():
        warnings.simplefilter('ignore', RuntimeWarning)          # a window no joint has a read in yet
        return np.nanmedian(per, axis=0) if len(res) else np.zeros(n_win)


def in_step_until(rec: Recording, res: dict[str, np.ndarray]) -> float:
    """The end of the last window [s] before the replay first leaves the recording: the median joint's
    RMS residual over a ``STEP_WINDOW_S`` window above ``OUT_OF_STEP_TICKS`` (physics left out of one
    joint raises that joint; the trunk going elsewhere raises every joint). The recording's end if never."""
    bad = np.flatnonzero(_window_rms(rec, res) > OUT_OF_STEP_TICKS)
    return rec.duration_s if not len(bad) else float(bad[0] * STEP_WINDOW_S)


@dataclass(frozen=True)
class PhaseRow:
    """RMS error of one joint in one phase over the reads judged [ticks]: the nominal replay, and the
    replay with the effects the tool found."""

    n_reads: int
    rmse_ticks_nominal: float
    rmse_ticks_fitted: float


@dataclass(frozen=True)
class WholeWalk:
    """The whole-walk comparison: the ground, the span judged (the replay in step with the recording
    with the effects found), and per joint and phase the RMS errors."""

    ground: Ground
    in_step_until_s: float
    nominal_in_step_until_s: float
    phases: dict                 # joint -> {phase name: PhaseRow}
    runtime_s: float

    def worst(self, phase_names=WHOLE_PHASES) -> tuple[Joint | str, str, float]:
        """(joint, phase, RMS) of the largest fitted RMS error over ``phase_names`` ('' where none is judged)."""
        best = ('', '', 0.0)
        for j, row in self.phases.items():
            for ph, v in row.items():
                if ph in phase_names and v.rmse_ticks_fitted > best[2]:
                    best = (j, ph, v.rmse_ticks_fitted)
        return best


def compare(rec: Recording, robot: Robot, fitted: Robot | None, ground: Ground, phases: dict,
            joints=None, replays: Replays | None = None) -> WholeWalk:
    """Replay the whole walk nominally and with the effects found (``fitted``; None: none found) and
    tabulate the error per joint and phase over the reads in step (``phases``: leg -> LegPhases).
    Each replay runs until it leaves the recording (:meth:`Replays.in_step`), the nominal one at least as
    far as the one with the effects is judged. ``replays``: the analysis's replays, reused."""
    import time
    t0 = time.perf_counter()
    joints = [j for j in (joints or rec.states) if j in rec.states]
    replays = replays or Replays(rec, robot, ground)
    if fitted is None:
        res0, until0 = replays.in_step(robot, joints)
        res1, until1 = res0, until0
    else:
        res1, until1 = replays.in_step(fitted, joints)
        res0, until0 = replays.in_step(robot, joints, need_s=until1)
    table = {}
    for j in joints:
        t = rec.states[j].t_s
        lab = whole_labels(phases[j.leg], t)
        judged = (t >= START_S) & (t < until1)
        row = {}
        for k, name in enumerate(WHOLE_PHASES):
            sel = judged & (lab == k)
            n = int(np.count_nonzero(sel))
            if n:
                row[name] = PhaseRow(n, float(np.sqrt(np.mean(res0[j][sel] ** 2))),
                                     float(np.sqrt(np.mean(res1[j][sel] ** 2))))
        table[j] = row
    return WholeWalk(ground, until1, until0, table, time.perf_counter() - t0)


def rec_ticks(rec: Recording, robot: Robot, joint: Joint) -> np.ndarray:
    """The recorded reads of ``joint`` in ticks."""
    return theta_to_tick(rec.states[joint].theta_rad, robot.servo)


__all__ = ['Ground', 'PhaseRow', 'WHOLE_PHASES', 'WholeWalk', 'compare', 'in_step_until', 'replay_walk', 'whole_labels']
