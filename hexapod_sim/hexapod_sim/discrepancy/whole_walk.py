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
"""
from __future__ import annotations

import bisect
import math
import warnings
from dataclasses import dataclass

import numpy as np

from hexapod_model.description import ALL_JOINTS, Robot, parse_joint_name
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
    """The recorded goal writes by the firmware tick they act on (the first at or after the write)."""
    writes: dict[int, dict[str, float]] = {}
    for j, cmd in rec.commands.items():
        ks = np.ceil(cmd.t_s / dt - 1e-9).astype(np.int64)
        for k, th in zip(ks.tolist(), cmd.theta_rad.tolist()):
            writes.setdefault(k, {})[j] = th
    return writes


def _sorted_writes(rec: Recording, dt: float) -> list[tuple[int, dict[str, float]]]:
    """:func:`_writes_by_tick` as (tick, goals) in tick order."""
    writes = _writes_by_tick(rec, dt)
    return [(k, writes[k]) for k in sorted(writes)]


def _start_angles(rec: Recording, sim) -> dict[str, float] | None:
    """The recording's first read of every joint, unless they are the plant's home pose (then None:
    a recording of the sim from its start replays from exactly the state it was made from)."""
    home = sim.true_joint_angles()
    first = {j: float(s.theta_rad[0]) for j, s in rec.states.items() if len(s)}
    tick = sim.robot.servo
    off = max((abs(float(theta_to_tick(v, tick) - theta_to_tick(home[ALL_JOINTS.index(j)], tick)))
               for j, v in first.items()), default=0.0)
    return None if off <= 1.0 else first


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
        self._cols = {j: ALL_JOINTS.index(j) for j in self.joints}
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
        self._meas: dict[str, np.ndarray] = {}
        self._writes: dict[float, list] = {}          # physics step -> the writes by tick (the same for every model)

    def _sorted_writes(self, rec: Recording, dt: float) -> list:
        if dt not in self._writes:
            self._writes[dt] = _sorted_writes(rec, dt)
        return self._writes[dt]

    def meas(self, joint: str) -> np.ndarray:
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

    def residuals(self, r: WalkReplay, joints=None, t_end_s: float | None = None) -> dict[str, np.ndarray]:
        """Recorded minus predicted ticks of ``joints`` (default the replay's) at the reads up to ``t_end_s``
        (default the replay's end); NaN where the replay has not yet come."""
        out = {}
        for j in (joints or r.joints):
            p = r.pred[j]
            if t_end_s is not None and t_end_s < r.t_end:
                p = p[:int(np.searchsorted(self.rec.states[j].t_s, t_end_s, side='right'))]
            out[j] = self.meas(j)[:len(p)] - p
        return out

    def in_step(self, model: Robot, joints, need_s: float = 0.0) -> tuple[dict[str, np.ndarray], float]:
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

    def worst(self, phase_names=WHOLE_PHASES) -> tuple[str, str, float]:
        """(joint, phase, RMS) of the largest fitted RMS error over ``phase_names``."""
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
        lab = whole_labels(phases[parse_joint_name(j)[0]], t)
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


WIDEN_MIN_GAIN_S = 2.0        # [s] longer in step for an effect found on some joints to be put on all


def widen(rec: Recording, robot: Robot, effects: list, ground: Ground, phases: dict, joints, ww: WholeWalk,
          progress=lambda msg: None, replays: Replays | None = None) -> tuple[list, dict, WholeWalk]:
    """Effects the swings found on some joints that the whole walk wants on every joint: where the replay
    with the effects leaves the recording, each kind found on part of the robot (not the servo law, not a
    payload) is tried on every analysed joint at the mean of its fitted values; kept when the replay then
    stays in step ``WIDEN_MIN_GAIN_S`` longer. -> (effects, {kind: the robot-wide effect}, comparison)."""
    from hexapod_sim.discrepancy.effects import BY_NAME
    wide: dict = {}
    if ww.in_step_until_s >= rec.duration_s:
        return list(effects), wide, ww
    replays = replays or Replays(rec, robot, ground)
    out = list(effects)
    for kind in dict.fromkeys(e.effect for e in effects):
        same = [e for e in out if e.effect == kind]
        if (kind not in BY_NAME or BY_NAME[kind].servo_law or kind == 'mass_error'      # (a dictionary term: as found)
                or set().union(*(e.joints for e in same)) >= set(joints)):
            continue
        key = BY_NAME[kind].key
        mean = float(np.mean([e.params[key] for e in same]))
        rest = [e for e in out if e.effect != kind]
        progress(f'whole walk: {kind} on every joint')
        ww2 = compare(rec, robot, robot.with_effects(rest + [BY_NAME[kind].make(joints, mean)]), ground, phases, joints,
                      replays)
        if ww2.in_step_until_s < ww.in_step_until_s + WIDEN_MIN_GAIN_S:
            continue
        until = min(ww2.in_step_until_s, START_S + SEARCH_HORIZON_S)       # the value, refitted on the whole walk
        fit, _ = _masks(rec, joints, until)
        v, _, _ = _search_one(rec, robot, rest, BY_NAME[kind], tuple(joints), ground, until, fit, progress,
                              bracket=(mean * (1 - WIDEN_BRACKET), mean * (1 + WIDEN_BRACKET)), replays=replays)
        trial_e = BY_NAME[kind].make(joints, v)
        out, wide[kind] = rest + [trial_e], trial_e
        ww = compare(rec, robot, robot.with_effects(out), ground, phases, joints, replays)
    return out, wide, ww


def whole_walk_check(rec: Recording, robot: Robot, effects, ground: Ground | None, phases: dict,
                     joints, search: bool = True, progress=lambda msg: None
                     ) -> tuple[WholeWalk, list[str], list[LoadedFind], dict]:
    """The whole-walk comparison of :func:`analyse`'s walk path, the effects found on part of the robot
    that it puts on every joint (:func:`widen`), what :func:`search_loaded` finds in its loaded phases
    (with ``search``), and the notes for the report. ``ground``: None takes the recording's
    (``/sim/scene``), else a flat floor."""
    if ground is not None:
        origin = 'as given'
    elif rec.ground is not None:
        ground, origin = rec.ground, "from the bag's /sim/scene"
    else:
        ground, origin = Ground(), 'assumed: a flat floor, as for a calibration walk; --terrain sets it'
    fitted = robot.with_effects(effects) if effects else None
    replays = Replays(rec, robot, ground)
    ww = compare(rec, robot, fitted, ground, phases, joints, replays)
    effects, wide, ww = widen(rec, robot, list(effects), ground, phases, joints, ww, progress, replays)
    finds = search_loaded(rec, robot, list(effects), ground, phases, ww, progress, replays) if search else []
    if finds:
        ww = compare(rec, robot, robot.with_effects(list(effects) + [f.effect for f in finds]), ground, phases, joints,
                     replays)
    notes = [f'whole walk: the recorded goals replayed through the MuJoCo hexapod on {ground.describe()} '
             f'({origin}), {ww.runtime_s:.1f} s']
    if ww.in_step_until_s < rec.duration_s:
        notes.append(f'whole walk: the replay left the recording at {ww.in_step_until_s:.1f} s of '
                     f'{rec.duration_s:.1f} s (every joint departs at once: the trunk went elsewhere); only reads '
                     'before it are judged' + ('' if ww.in_step_until_s >= START_S + SEARCH_MIN_IN_STEP_S else
                                               f'; under {SEARCH_MIN_IN_STEP_S:g} s in step, nothing is fitted on '
                                               'it (is the ground right? --terrain)'))
    j, ph, v = ww.worst(LOADED_PHASES)
    if j:
        notes.append(f'whole walk: largest RMS error where the legs carry the body: {j} in {ph.replace("_", "-")}, '
                     f'{v:.2f} ticks' + (' (tick rounding)' if v <= ROUNDING_TICKS else ''))
    for kind in wide:
        notes.append(f'whole walk: {kind.replace("_", " ")} found on part of the robot keeps the replay in step only '
                     'when it acts on every joint: put on the whole robot')
    return ww, notes, finds, wide


# Effects that show where a leg carries the body (a load reversal, a hold under load) more than in a free
# swing, searched for on the whole walk when its loaded phases leave more than tick rounding.
LOADED_CANDIDATES = ('backlash', 'static_friction', 'compliance_deadband')
ROBOT_WIDE_MIN_JOINTS = 6     # this many joints in excess: a robot-wide scope is tried too
SEARCH_BLOCK_S = 2.0          # alternating fit / held-out blocks of the search [s]
SEARCH_GRID = 5               # log-spaced values over the candidate's range, then golden-section steps
SEARCH_REFINE = 4
SEARCH_MIN_RATIO = 1.5        # held-out RMS improvement an effect must reach on its joints
SEARCH_MIN_EXPLAINED = 0.75   # and the share of their excess over rounding it must explain
ROUNDING_RMS = 0.29           # uniform tick rounding: 1/sqrt(12)
EDGE_FACTOR = 1.1             # a fit within this factor of its range's low end is no measurement: not named
WIDEN_BRACKET = 0.2           # a widened effect's value is refitted within +-20 % of the parts' mean
SEARCH_CHECK_S = 0.5          # [s] of replay between two looks at a candidate's error so far
SEARCH_HORIZON_S = 20.0       # [s] of the walk (in step) the search replays: its cost does not grow with the walk
SEARCH_MIN_IN_STEP_S = 5.0    # [s] in step the search needs (fewer: the ground is likely not the walk's)
MAX_JOINT_SCOPES = 3          # single-joint scopes tried: the joints with the largest loaded-phase error


@dataclass(frozen=True)
class LoadedFind:
    """An effect the whole walk shows: held-out RMS error on its joints [ticks] without and with it."""

    effect: object                  # hexapod_model.description.Effect
    phase: str                      # the loaded phase where its joints' error was largest
    heldout_rmse_ticks_before: float
    heldout_rmse_ticks_after: float


def _loaded_excess(ww: WholeWalk) -> list[tuple[str, float]]:
    """(joint, RMS) of the joints whose error over the loaded phases, with the effects found, is above tick
    rounding, the largest first."""
    out = []
    for j, row in ww.phases.items():
        rows = [row[ph] for ph in LOADED_PHASES if ph in row]
        n = sum(r.n_reads for r in rows)
        rms = math.sqrt(sum(r.n_reads * r.rmse_ticks_fitted ** 2 for r in rows) / n) if n else 0.0
        if rms > ROUNDING_TICKS:
            out.append((j, rms))
    return sorted(out, key=lambda x: -x[1])


def _masks(rec: Recording, joints, until_s: float):
    """(fit, held-out) read masks per joint: alternating ``SEARCH_BLOCK_S`` blocks after ``START_S``."""
    fit, hold = {}, {}
    for j in joints:
        t = rec.states[j].t_s
        ok = (t >= START_S) & (t < until_s)
        even = (np.floor(t / SEARCH_BLOCK_S).astype(np.int64) % 2) == 0
        fit[j], hold[j] = ok & even, ok & ~even
    return fit, hold


def _rms(rec, robot, pred: dict, joints, masks) -> float:
    sq, n = 0.0, 0
    for j in joints:
        r = (rec_ticks(rec, robot, j)[:len(pred[j])] - pred[j])[masks[j][:len(pred[j])]]
        sq += float(np.sum(r ** 2))
        n += len(r)
    return math.sqrt(sq / n) if n else math.nan


class _Trial:
    """The fit reads' RMS error [ticks] of the whole walk replayed with one candidate value, replayed only
    as far as a comparison needs: the squared error summed over the reads replayed so far, over the count of
    all the fit reads, bounds the whole from below."""

    def __init__(self, replays: Replays, model: Robot, scope, until_s: float, fit: dict):
        self.replays, self.scope = replays, tuple(scope)
        self.replay = replays.get(model, scope, until_s, keep=False)
        self.fit = fit
        self.masks = {j: fit[j][:len(self.replay.pred[j])] for j in scope}
        self.n = sum(int(np.count_nonzero(m)) for m in self.masks.values())
        self.t, self.sq, self.value = 0.0, 0.0, None

    @property
    def finished(self) -> bool:
        return self.value is not None

    def advance(self) -> None:
        """Replay ``SEARCH_CHECK_S`` further (the exact RMS once the replay is done)."""
        self.t += SEARCH_CHECK_S
        self.replay.run_to(self.t)
        if self.replay.finished:
            self.value = _rms(self.replays.rec, self.replays.robot, self.replay.pred, self.scope, self.fit)
            return
        res = self.replays.residuals(self.replay, self.scope)
        self.sq = sum(float(np.nansum(res[j][self.masks[j]] ** 2)) for j in self.scope)

    def bound(self) -> float:
        return self.sq / self.n if self.n else 0.0

    def exceeds(self, c: float) -> bool:
        """Its RMS is certainly above ``c`` (the margin covers the sums' rounding)."""
        return self.n > 0 and self.sq > c * c * self.n * (1.0 + 1e-9)


def _settle(trials: list[_Trial]) -> list[float]:
    """The trials' RMS errors, each trial replayed only until it is known to be above the smallest of them
    (then inf: above it). Always the one with the smallest lower bound runs next, so the smallest is
    replayed whole and the others stop once their error so far passes it; the minimum and its position
    are those of the whole replays."""
    while True:
        done = [t.value for t in trials if t.finished and not math.isnan(t.value)]
        least = min(done) if done else None
        open_ = [t for t in trials if not t.finished and not (least is not None and t.exceeds(least))]
        if not open_:
            return [t.value if t.finished else math.inf for t in trials]
        min(open_, key=_Trial.bound).advance()


def _search_one(rec, robot, base: list, cand, scope, ground, until_s, fit, progress,
                bracket: tuple[float, float] | None = None, replays: Replays | None = None
                ) -> tuple[float, float, WalkReplay]:
    """(value, fit RMS, its replay) of ``cand`` on ``scope`` minimising the fit reads' RMS error of the whole
    walk, over the candidate's range (or ``bracket``): a log-spaced grid, then golden-section steps between
    the best point's neighbours. Each comparison replays its candidates only as far as it needs
    (:func:`_settle`), and a golden-section step reuses the interior point it keeps where the logarithms give
    it exactly again (about every other step; a value one rounding away is replayed, as the walk's replay
    is that sensitive)."""
    replays = replays or Replays(rec, robot, ground)
    made: list[tuple[float, _Trial]] = []

    def trial(v):
        for x, t in made:
            if x == v:        # exactly: the open-loop replay of a walk moves by a tick for a 1e-16 change
                return t
        progress(f'whole walk: {cand.effect} {v:.3g} on {len(scope)} joint(s)')
        t = _Trial(replays, robot.with_effects(base + [cand.make(scope, v)]), scope, until_s, fit)
        made.append((v, t))
        return t

    lo, hi = bracket or (cand.lo, cand.hi)
    grid = np.geomspace(max(lo, 1e-6), hi, SEARCH_GRID)
    trials = [trial(float(v)) for v in grid]
    costs = _settle(trials)
    k = int(np.nanargmin(costs))
    a, b = grid[max(k - 1, 0)], grid[min(k + 1, len(grid) - 1)]
    best = (float(grid[k]), costs[k], trials[k])
    g = (math.sqrt(5) - 1) / 2
    for _ in range(SEARCH_REFINE):               # golden section in log space between the neighbours
        la, lb = math.log(a), math.log(b)
        x1, x2 = math.exp(lb - g * (lb - la)), math.exp(la + g * (lb - la))
        t1, t2 = trial(x1), trial(x2)
        c1, c2 = _settle([t1, t2])
        for x, c, t in ((x1, c1, t1), (x2, c2, t2)):
            if c < best[1]:
                best = (x, c, t)
        a, b = (a, x2) if c1 < c2 else (x1, b)
        made[:] = [(x, t) for x, t in made if t in (t1, t2)]      # the next step can only reuse these
    return best[0], best[1], best[2].replay


def search_loaded(rec: Recording, robot: Robot, effects: list, ground: Ground, phases: dict, ww: WholeWalk,
                  progress=lambda msg: None, replays: Replays | None = None) -> list[LoadedFind]:
    """Effects of :data:`LOADED_CANDIDATES` that explain what the whole walk's loaded phases leave, on the
    joints that leave more than tick rounding (each alone; and the whole robot when many do), fitted on
    alternate 2 s blocks of the whole walk and judged on the others. At most one effect per joint."""
    from hexapod_sim.discrepancy.effects import BY_NAME
    excess = _loaded_excess(ww)
    if not excess or ww.in_step_until_s < START_S + SEARCH_MIN_IN_STEP_S:
        return []
    joints = list(ww.phases)
    until = min(ww.in_step_until_s, START_S + SEARCH_HORIZON_S)
    fit, hold = _masks(rec, joints, until)
    scopes = [(j,) for j, _ in excess[:MAX_JOINT_SCOPES]]
    scopes += [tuple(joints)] if len(excess) >= ROBOT_WIDE_MIN_JOINTS else []
    base = list(effects)
    replays = replays or Replays(rec, robot, ground)
    r0 = replays.get(robot.with_effects(base), joints, until)
    r0.run_to(until)
    base_pred = {j: r0.pred[j][:int(np.searchsorted(rec.states[j].t_s, until, side='right'))] for j in joints}
    found: list[LoadedFind] = []
    for scope in sorted(scopes, key=len, reverse=True):
        if any(j in f.effect.joints for f in found for j in scope):
            continue
        before = _rms(rec, robot, base_pred, scope, hold)
        trials = []
        for name in LOADED_CANDIDATES:
            cand = BY_NAME[name]
            v, _, r = _search_one(rec, robot, base, cand, scope, ground, until, fit, progress, replays=replays)
            trials.append((_rms(rec, robot, r.pred, scope, hold), cand.make(scope, v)))
        after, eff = min(trials, key=lambda x: x[0])
        explained = (before ** 2 - after ** 2) / max(before ** 2 - ROUNDING_RMS ** 2, 1e-9)
        c = BY_NAME[eff.effect]
        at_edge = eff.params[c.key] <= c.lo * EDGE_FACTOR      # the fit ran to the smallest plausible value
        if before / max(after, 1e-9) >= SEARCH_MIN_RATIO and explained >= SEARCH_MIN_EXPLAINED and not at_edge:
            worst = max(LOADED_PHASES, key=lambda ph: max((ww.phases[j][ph].rmse_ticks_fitted for j in scope
                                                           if ph in ww.phases[j]), default=0.0))
            found.append(LoadedFind(eff, worst, before, after))
            base.append(eff)
    return found


def rec_ticks(rec: Recording, robot: Robot, joint: str) -> np.ndarray:
    """The recorded reads of ``joint`` in ticks."""
    return theta_to_tick(rec.states[joint].theta_rad, robot.servo)


__all__ = ['Ground', 'PhaseRow', 'WHOLE_PHASES', 'WholeWalk', 'compare', 'in_step_until', 'replay_walk',
           'search_loaded', 'whole_labels', 'whole_walk_check', 'widen']
