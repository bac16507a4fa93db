"""The whole walk judged: its replay against the recording phase by phase, and the searches on it.

The replays of one analysis (:class:`Replays`, each a :class:`~.whole_walk.WalkReplay`) run until they leave
the recording: :func:`in_step_until` finds that moment, and only reads before it are judged
(:func:`compare`). Phases (:data:`WHOLE_PHASES`): the gait phases of :mod:`.segments`, with the first
``TOUCHDOWN_S`` of a stance after a swing-down (the leg takes its share of the body's weight) and the first
``LIFT_OFF_S`` of a swing-up (it gives the share up) told apart.

Effects the swings found on part of the robot that the whole walk wants on every joint (:func:`widen`), and
the searches on the whole walk's replay that :mod:`.loaded_search` runs in its loaded phases;
:mod:`.whole_walk_findings` runs them in the analysis of a walk.
"""
from __future__ import annotations

import math
import time
import warnings
from dataclasses import dataclass

import numpy as np

from hexapod_model.description import Robot
from hexapod_model.joints import Joint
from hexapod_sim.discrepancy.recording import Recording
from hexapod_sim.discrepancy.segments import PHASES, LegPhases
from hexapod_sim.discrepancy.whole_walk import ReplayInputs, WalkReplay, rec_ticks
from hexapod_sim.physics.terrain import Ground

WHOLE_PHASES = ('swing_up', 'swing_forward', 'swing_down', 'stance', 'touchdown', 'lift_off', 'leveling')
TOUCHDOWN_S = 0.1          # [s] of stance after a swing-down stops: the leg takes up the body's weight
LIFT_OFF_S = 0.1           # [s] of swing-up after it starts: the leg gives up its share
STEP_WINDOW_S = 0.5        # [s] windows in which the replay is judged in step with the recording
OUT_OF_STEP_TICKS = 1.0    # the median joint's RMS over a window above this: the trunk went elsewhere
START_S = 0.2              # [s] at the start left out (the first reads settle the pose)
LOADED_PHASES = ('stance', 'touchdown', 'lift_off', 'leveling')   # where the legs carry the body
SWING_PHASES = ('swing_up', 'swing_forward', 'swing_down')        # where the free-leg model judges a leg
ROUNDING_TICKS = 0.5       # a phase's RMS error at most this is tick rounding (uniform rounding: 0.29)
WIDEN_MIN_GAIN_S = 2.0        # [s] longer in step for an effect found on some joints to be put on all
AGREES_SHARE = 0.8            # the whole-walk replay in step over this share of a walk can clear a joint
AGREES_MIN_READS = 20         # a phase judged on fewer reads says nothing either way


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


class Replays:
    """The whole-walk replays of one analysis (one recording, robot description and ground), each made once
    and run only as far as a caller needs: the nominal replay is compared against every set of effects
    tried, and the replay with the effects found is the search's starting point. A replay serves any span
    up to its own (the first steps of a longer replay are the shorter one's, write for write)."""

    def __init__(self, rec: Recording, robot: Robot, ground: Ground):
        self.rec, self.robot, self.ground = rec, robot, ground
        self._made: list[tuple[Robot, tuple, WalkReplay]] = []
        self._meas: dict[Joint, np.ndarray] = {}
        self._inputs = ReplayInputs(rec, ground)      # the writes and the terrain (the same for every model)

    @property
    def replayed_s(self) -> float:
        """The physics time [s] all its replays have run together."""
        return self._inputs.replayed_s

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
        r = WalkReplay(self.rec, model, self.ground, joints, t_end_s, inputs=self._inputs)
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


def compare(replays: Replays, fitted: Robot | None, phases: dict, joints=None) -> WholeWalk:
    """Replay the whole walk nominally and with the effects found (``fitted``; None: none found) and
    tabulate the error per joint and phase over the reads in step (``phases``: leg -> LegPhases).
    Each replay runs until it leaves the recording (:meth:`Replays.in_step`), the nominal one at least as
    far as the one with the effects is judged. ``replays``: the analysis's replays (its recording, nominal
    robot and ground), reused."""
    t0 = time.perf_counter()
    rec, robot = replays.rec, replays.robot
    joints = [j for j in (joints or rec.states) if j in rec.states]
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
    return WholeWalk(replays.ground, until1, until0, table, time.perf_counter() - t0)


def widen(replays: Replays, effects: list, phases: dict, joints, ww: WholeWalk,
          progress=lambda msg: None) -> tuple[list, dict, WholeWalk]:
    """Effects the swings found on some joints that the whole walk wants on every joint: where the replay
    with the effects leaves the recording, each kind found on part of the robot (not the servo law, not a
    payload) is tried on every analysed joint at the mean of its fitted values; kept when the replay then
    stays in step ``WIDEN_MIN_GAIN_S`` longer. -> (effects, {kind: the robot-wide effect}, comparison)."""
    from hexapod_sim.discrepancy.effects import BY_NAME
    rec, robot = replays.rec, replays.robot
    wide: dict = {}
    if ww.in_step_until_s >= rec.duration_s:
        return list(effects), wide, ww
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
        ww2 = compare(replays, robot.with_effects(rest + [BY_NAME[kind].make(joints, mean)]), phases, joints)
        if ww2.in_step_until_s < ww.in_step_until_s + WIDEN_MIN_GAIN_S:
            continue
        until = min(ww2.in_step_until_s, START_S + SEARCH_HORIZON_S)       # the value, refitted on the whole walk
        fit, _ = search_masks(rec, joints, until)
        v, _, _ = search_one(replays, rest, BY_NAME[kind], tuple(joints), until, fit, progress,
                             bracket=(mean * (1 - WIDEN_BRACKET), mean * (1 + WIDEN_BRACKET)))
        trial_e = BY_NAME[kind].make(joints, v)
        out, wide[kind] = rest + [trial_e], trial_e
        ww = compare(replays, robot.with_effects(out), phases, joints)
    return out, wide, ww


def walk_ground(rec: Recording, ground: Ground | None) -> tuple[Ground, str]:
    """(ground, where it comes from) of the whole-walk replay: ``ground`` as given, else the recording's
    (``/sim/scene``), else a flat floor."""
    if ground is not None:
        return ground, 'as given'
    if rec.ground is not None:
        return rec.ground, "from the bag's /sim/scene"
    return Ground(), 'assumed: a flat floor, as for a calibration walk; --terrain sets it'


def follows_to_rounding(in_step_until_s: float, duration_s: float, rows) -> bool:
    """The rule by which the whole walk clears a joint: a replay in step over at least ``AGREES_SHARE`` of the
    walk, and on that joint every phase judged on at least ``AGREES_MIN_READS`` reads (``rows``: (reads,
    RMS [ticks]) per phase; at least one) within tick rounding."""
    if not in_step_until_s >= AGREES_SHARE * duration_s:
        return False
    judged = [rms for n, rms in rows if n >= AGREES_MIN_READS]
    return bool(judged) and max(judged) <= ROUNDING_TICKS


def follows(rec: Recording, res: dict, until_s: float, phases: dict, joints) -> bool:
    """Whether a whole-walk replay (``res``: its residuals, in step until ``until_s``) follows ``joints`` to
    tick rounding (:func:`follows_to_rounding`)."""
    for j in joints:
        t = rec.states[j].t_s
        r = res[j]
        t = t[:len(r)]
        lab = whole_labels(phases[j.leg], t)
        judged = (t >= START_S) & (t < until_s)
        rows = []
        for k in range(len(WHOLE_PHASES)):
            v = r[judged & (lab == k)]
            v = v[np.isfinite(v)]
            rows.append((len(v), float(np.sqrt(np.mean(v ** 2))) if len(v) else 0.0))
        if not follows_to_rounding(until_s, rec.duration_s, rows):
            return False
    return True


def joint_rms(rec: Recording, res: dict, joints, until_s: float) -> float:
    """RMS residual [ticks] of ``joints`` over the reads from ``START_S`` to ``until_s`` (a read the replay
    has not reached counts as out of step: inf)."""
    sq, n = 0.0, 0
    for j in joints:
        t = rec.states[j].t_s
        sel = (t >= START_S) & (t < until_s)
        r = res[j]
        if len(r) < int(np.count_nonzero(t < until_s)):
            return math.inf
        v = r[sel[:len(r)]]
        v = v[np.isfinite(v)]                   # a read the replay predicts no value for
        sq += float(np.sum(v ** 2))
        n += len(v)
    return math.sqrt(sq / n) if n else math.inf


# The searches on the whole walk (:func:`search_one`; the loaded-phase search is :mod:`.loaded_search`'s)
SEARCH_BLOCK_S = 2.0          # alternating fit / held-out blocks of the search [s]
SEARCH_GRID = 9               # log-spaced values over the candidate's range, then golden-section steps
SEARCH_REFINE = 4
SEARCH_MIN_RATIO = 1.5        # held-out RMS improvement an effect must reach on its joints
SEARCH_MIN_EXPLAINED = 0.75   # and the share of their excess over rounding it must explain
ROUNDING_RMS = 0.29           # uniform tick rounding: 1/sqrt(12)
WIDEN_BRACKET = 0.2           # a widened effect's value is refitted within +-20 % of the parts' mean
SEARCH_CHECK_S = 0.5          # [s] of replay between two looks at a candidate's error so far
SEARCH_HORIZON_S = 20.0       # [s] of the walk (in step) the search replays: its cost does not grow with the walk
SEARCH_MIN_IN_STEP_S = 5.0    # [s] in step the search needs (fewer: the ground is likely not the walk's)


def search_masks(rec: Recording, joints, until_s: float):
    """(fit, held-out) read masks per joint: alternating ``SEARCH_BLOCK_S`` blocks after ``START_S``."""
    fit, hold = {}, {}
    for j in joints:
        t = rec.states[j].t_s
        ok = (t >= START_S) & (t < until_s)
        even = (np.floor(t / SEARCH_BLOCK_S).astype(np.int64) % 2) == 0
        fit[j], hold[j] = ok & even, ok & ~even
    return fit, hold


def masked_rms(replays: Replays, pred: dict, joints, masks) -> float:
    sq, n = 0.0, 0
    for j in joints:
        r = (replays.meas(j)[:len(pred[j])] - pred[j])[masks[j][:len(pred[j])]]
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
            self.value = masked_rms(self.replays, self.replay.pred, self.scope, self.fit)
            return
        res = self.replays.residuals(self.replay, self.scope)
        self.sq = sum(float(np.nansum(res[j][self.masks[j]] ** 2)) for j in self.scope)

    def bound(self) -> float:
        return self.sq / self.n if self.n else 0.0

    def exceeds(self, c: float) -> bool:
        """Its RMS is certainly above ``c`` (the margin covers the sums' rounding)."""
        return self.n > 0 and self.sq > c * c * self.n * (1.0 + 1e-9)


def _settle(trials: list[_Trial], worth_below: float = math.inf) -> list[float]:
    """The trials' RMS errors, each trial replayed only until it is known to be above the smallest of them
    or above ``worth_below`` (then inf: above it). Always the one with the smallest lower bound runs next,
    so the smallest is replayed whole and the others stop once their error so far passes it; the minimum
    and its position are those of the whole replays wherever the minimum is below ``worth_below``."""
    while True:
        done = [t.value for t in trials if t.finished and not math.isnan(t.value)]
        limit = min([*done, worth_below])
        open_ = [t for t in trials if not t.finished and not t.exceeds(limit)]
        if not open_:
            return [t.value if t.finished else math.inf for t in trials]
        min(open_, key=_Trial.bound).advance()


def search_one(replays: Replays, base: list, cand, scope, until_s, fit, progress,
                bracket: tuple[float, float] | None = None,
                worth_below: float = math.inf) -> tuple[float, float, WalkReplay] | None:
    """(value, fit RMS, its replay) of ``cand`` on ``scope`` minimising the fit reads' RMS error of the whole
    walk, over the candidate's range (or ``bracket``): a log-spaced grid, then golden-section steps between
    the best point's neighbours. Each comparison replays its candidates only as far as it needs
    (:func:`_settle`), and a golden-section step reuses the interior point it keeps where the logarithms give
    it exactly again (about every other step; a value one rounding away is replayed, as the walk's replay
    is that sensitive). None where no grid value's fit RMS is below ``worth_below``: the grid's values are
    then replayed only until each is known to be above it."""
    robot = replays.robot
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
    costs = _settle(trials, worth_below)
    k = int(np.nanargmin(costs))
    if not costs[k] < worth_below:
        return None
    a, b = grid[max(k - 1, 0)], grid[min(k + 1, len(grid) - 1)]
    best = (float(grid[k]), costs[k], trials[k])
    g = (math.sqrt(5) - 1) / 2
    # golden section in log space between the neighbours
    for _ in range(SEARCH_REFINE):
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


__all__ = ['PhaseRow', 'Replays', 'WHOLE_PHASES', 'WholeWalk', 'compare', 'follows', 'follows_to_rounding',
           'in_step_until', 'joint_rms', 'walk_ground', 'whole_labels', 'widen']
