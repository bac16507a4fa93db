"""The whole walk's loaded phases searched (:func:`search_loaded`): backlash, break-away friction and the
dead-band fitted on the replay of the whole walk (:func:`~.whole_walk_search.search_one`) on the joints
its loaded phases leave above tick rounding, judged on held-out blocks of the walk, and named only where
the effects already named, refitted, do not explain as much (:func:`_rival`).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from hexapod_model.description import Effect, Robot
from hexapod_sim.discrepancy.whole_walk_search import (
    LOADED_PHASES,
    ROUNDING_RMS,
    ROUNDING_TICKS,
    SEARCH_HORIZON_S,
    SEARCH_MIN_EXPLAINED,
    SEARCH_MIN_IN_STEP_S,
    SEARCH_MIN_RATIO,
    START_S,
    Replays,
    WholeWalk,
    masked_rms,
    search_masks,
    search_one,
)

# Effects that show where a leg carries the body (a load reversal, a hold under load) more than in a free
# swing, searched for on the whole walk when its loaded phases leave more than tick rounding.
LOADED_CANDIDATES = ('backlash', 'static_friction', 'compliance_deadband')
# Swing effects fitted again on the whole walk on one joint where the swings fitted them on that joint and did
# not name them: beside a larger effect on its leg, a small friction changes the swings by less than the walk's
# bar, but the whole walk shows it at every load reversal of the joint. Named only where the whole walk's value
# is within SWING_AGREEMENT of the swings' (the same friction in both): on a walk whose supply sags, Coulomb
# friction the swings never fitted passed on one tibia of the whole walk.
SWING_CANDIDATES = ('coulomb_friction',)
SWING_AGREEMENT = 1.5
ROBOT_WIDE_MIN_JOINTS = 6     # this many joints in excess: a robot-wide scope is tried too
EDGE_FACTOR = 1.5             # a fit within this factor of its range's low end is no measurement: not named
MAX_JOINT_SCOPES = 4          # single-joint scopes tried: the joints with the largest loaded-phase error
# A candidate whose grid does not explain the fit blocks by this ratio is not named (an effect shows on the
# blocks it is fitted on), and its grid values replay only until each is known to be above it: on a scope
# where nothing is found, a value that changes the open-loop replay at all leaves the walk's step and its
# error grows with the replay, so these replays would otherwise run to the end of the search horizon.
FIT_MIN_RATIO = 1.1
# A scope is searched only where the fit or the held-out blocks leave at least this multiple of tick rounding
# (ROUNDING_RMS): an effect must bring its error down by SEARCH_MIN_RATIO, and a prediction follows reads
# rounded to whole ticks better than their rounding only by chance (the smallest held-out error before of an
# effect named on the walks of the walk and random benches: 0.49 ticks). On walks whose loaded phases sit a
# little above rounding on many joints (the blocks; a servo law fitted robot-wide) these scopes took most of
# the analysis and never named anything.
FLOOR_RATIO = SEARCH_MIN_RATIO
# The walk time [s] the search may replay (all its replays together, 1 ms physics steps) before it begins no
# further scope; a scope begun is searched to its end. The robot-wide scope comes first, then the joints by their
# loaded-phase error, largest first, so what the budget leaves out is the joints nearest tick rounding. 800 s is
# 40 replays of the search horizon, about 25 s of one core (31 us a step with the search's bookkeeping). On the
# walks of the walk and random benches the latest scope that named anything began at 526 s of replay (backlash
# on a femur, the fourth joint searched); the tripod walk over the blocks with Coulomb friction and a payload
# replayed 2516 s in five scopes and named nothing (93 s for the one-minute walk).
SEARCH_BUDGET_S = 800.0
RIVAL_BRACKET = 0.05          # a named effect refitted within +-5 % of its value is a new loaded effect's rival
RIVAL_MARGIN = 1.1            # and the new effect is named only when its held-out RMS beats the rival's by this


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


def _least_measured(cand, robot: Robot) -> float:
    """The least value of a loaded-phase candidate the whole walk names: ``EDGE_FACTOR`` times its range's low
    end (a fit that runs towards the smallest plausible value is no measurement: on walks it gave break-away
    friction of 0.09 N m and play of 0.17 degrees on joints that have neither), and for play and the
    dead-band at least one tick, the reads' resolution (the dead-band register holds whole ticks)."""
    least = cand.lo * EDGE_FACTOR
    if cand.effect == 'backlash':
        least = max(least, robot.servo.rad_per_tick)
    elif cand.effect == 'compliance_deadband':
        least = max(least, 1.0)
    return least


@dataclass(frozen=True)
class _Refit:
    """A named effect of one parameter with that parameter free (the candidate interface of
    :func:`search_one`; it acts on its own joints whatever scope is judged)."""

    named: Effect
    key: str

    @property
    def effect(self) -> str:
        return self.named.effect

    def make(self, _joints, value: float) -> Effect:
        return Effect(self.named.effect, self.named.joints, {self.key: float(value)})


def _rival(replays: Replays, base: list, scope, until_s: float, fit: dict, hold: dict,
           progress) -> tuple[float, list] | None:
    """The best of the named one-parameter effects refitted within ``RIVAL_BRACKET`` of its value on the
    whole walk (fitted on ``scope`` and its own joints): on the blocks a torque limit 0.5 % low left a tibia
    1.3 ticks off in stance, and a load friction 0.5 % high moved another leg's touchdown by 3.7 ticks; a
    new loaded effect must explain such an excess better than the named effects at their right values.
    -> (held-out RMS on ``scope``, ``base`` with it refitted in its place), or None."""
    best = None
    for i, e in enumerate(base):
        ((key, v0),) = e.params.items() if len(e.params) == 1 else ((None, 0.0),)
        if key is None or not v0 > 0:
            continue
        rest = base[:i] + base[i + 1:]
        judged = tuple(dict.fromkeys(tuple(scope) + tuple(j for j in e.joints if j in fit)))
        v, _, r = search_one(replays, rest, _Refit(e, key), judged, until_s, fit, progress,
                              bracket=(v0 * (1 - RIVAL_BRACKET), v0 * (1 + RIVAL_BRACKET)))
        rms = masked_rms(replays, r.pred, scope, hold)
        if best is None or rms < best[0]:
            best = (rms, rest[:i] + [_Refit(e, key).make(e.joints, v)] + rest[i:])
    return best


def _base_pred(replays: Replays, base: list, joints, until_s: float) -> dict:
    """The reads of ``joints`` up to ``until_s`` predicted by the whole walk replayed with ``base``."""
    r0 = replays.get(replays.robot.with_effects(base), joints, until_s)
    r0.run_to(until_s)
    return {j: r0.pred[j][:int(np.searchsorted(replays.rec.states[j].t_s, until_s, side='right'))] for j in joints}


def _passes(before: float, after: float) -> bool:
    """A held-out improvement by ``SEARCH_MIN_RATIO`` that explains ``SEARCH_MIN_EXPLAINED`` of the excess."""
    explained = (before ** 2 - after ** 2) / max(before ** 2 - ROUNDING_RMS ** 2, 1e-9)
    return before / max(after, 1e-9) >= SEARCH_MIN_RATIO and explained >= SEARCH_MIN_EXPLAINED


def _pooled(scope, masks: tuple[dict, dict], rms: tuple[float, float]) -> float:
    """The RMS over both halves' reads of ``scope`` from each half's RMS."""
    n = [sum(int(np.count_nonzero(m[j])) for j in scope) for m in masks]
    return math.sqrt((n[0] * rms[0] ** 2 + n[1] * rms[1] ** 2) / max(n[0] + n[1], 1))


def _best_on_scope(replays: Replays, base: list, base_pred: dict, scope, until_s: float, fit: dict, hold: dict,
                   progress, swing_values: dict) -> tuple[float, float, Effect, float] | None:
    """The candidate that best explains ``scope``'s held-out reads: (RMS before, after, the effect, its RMS on
    the held-out blocks). Each candidate is fitted on the fit blocks and judged on the held-out ones. When
    that does not pass (:func:`_passes`) but a candidate explains the fit blocks by the ratio, the
    held-out blocks may hold little of what the fit blocks show (a break-away friction that holds a tibia in
    a few stances: 0.95 ticks on the fit blocks, 0.39 on the others); that candidate is then also fitted on
    the held-out blocks and judged on the fit blocks, both halves judged together, at the geometric mean of
    its two values (not where both halves would fail even with the fit blocks at their least error found).
    A candidate that does not explain the fit blocks by :data:`FIT_MIN_RATIO` is left out.
    ``swing_values``: {swing candidate: the value the swings fitted on ``scope``}, tried too and kept only
    where the whole walk's value agrees (:data:`SWING_AGREEMENT`). A kind named on every joint of ``scope``
    already is not tried again (its value is :func:`_rival`'s to refit). None: no candidate left, or
    ``scope`` too close to tick rounding on both halves for any effect to pass (:data:`FLOOR_RATIO`)."""
    from hexapod_sim.discrepancy.effects import BY_NAME
    before = masked_rms(replays, base_pred, scope, hold)
    before_fit = masked_rms(replays, base_pred, scope, fit)
    if not max(before, before_fit) >= FLOOR_RATIO * ROUNDING_RMS:
        return None
    named = {(e.effect, j) for e in base for j in e.joints}
    trials = []
    for name in LOADED_CANDIDATES + tuple(swing_values):
        if all((name, j) in named for j in scope):
            continue
        cand = BY_NAME[name]
        got = search_one(replays, base, cand, scope, until_s, fit, progress, worth_below=before_fit / FIT_MIN_RATIO)
        if got is None:
            continue
        v, c_fit, r = got
        if name in swing_values and not 1 / SWING_AGREEMENT <= v / swing_values[name] <= SWING_AGREEMENT:
            continue
        trials.append((masked_rms(replays, r.pred, scope, hold), c_fit, cand, v))
    if not trials:
        return None
    after, _, cand, v = min(trials, key=lambda x: x[0])
    if _passes(before, after):
        return before, after, cand.make(scope, v), after
    a_hold, c_fit, cand2, v1 = min(trials, key=lambda x: x[1])
    if not before_fit / max(c_fit, 1e-9) >= SEARCH_MIN_RATIO:
        return before, after, cand.make(scope, v), after
    pooled_before = _pooled(scope, (fit, hold), (before_fit, before))
    # fitted on the held-out blocks, a value leaves the fit blocks at no less than c_fit, their least error
    # found: where even that does not pass, the second fit is not run
    if not _passes(pooled_before, _pooled(scope, (fit, hold), (c_fit, a_hold))):
        return before, after, cand.make(scope, v), after
    v2, _, r2 = search_one(replays, base, cand2, scope, until_s, hold, progress)
    a_fit = masked_rms(replays, r2.pred, scope, fit)
    return (pooled_before, _pooled(scope, (fit, hold), (a_fit, a_hold)), cand2.make(scope, math.sqrt(v1 * v2)), a_hold)


def search_loaded(replays: Replays, effects: list, ww: WholeWalk, progress=lambda msg: None,
                  swing_fits: dict | None = None, budget_s: float = SEARCH_BUDGET_S
                  ) -> tuple[list[LoadedFind], list[tuple], list[tuple]]:
    """Effects of :data:`LOADED_CANDIDATES` that explain what the whole walk's loaded phases leave, on the
    joints that leave more than tick rounding (each alone; and the whole robot when many do), fitted on
    alternate 2 s blocks of the whole walk and judged on the others (:func:`_best_on_scope`). At most one
    effect per joint; none where a named effect at a refitted value explains the excess as well
    (:func:`_rival`), which is refitted instead (a find of an earlier scope then takes its refitted value).
    ``swing_fits``: {(effect, joint): value} the swings fitted on one joint and did not name; those of
    :data:`SWING_CANDIDATES` are tried on their joint too. A scope is begun only while the search has replayed
    less than ``budget_s`` of walk (:data:`SEARCH_BUDGET_S`).
    -> (finds, [(named effect, refitted)], [(scope not searched, its loaded-phase RMS error)])."""
    from hexapod_sim.discrepancy.effects import BY_NAME
    rec, robot = replays.rec, replays.robot
    excess = _loaded_excess(ww)
    if not excess or ww.in_step_until_s < START_S + SEARCH_MIN_IN_STEP_S:
        return [], [], []
    joints = list(ww.phases)
    until = min(ww.in_step_until_s, START_S + SEARCH_HORIZON_S)
    fit, hold = search_masks(rec, joints, until)
    scopes = [(j,) for j, _ in excess[:MAX_JOINT_SCOPES]]
    scopes += [tuple(joints)] if len(excess) >= ROBOT_WIDE_MIN_JOINTS else []
    base = list(effects)
    base_pred = _base_pred(replays, base, joints, until)
    swing_fits = swing_fits or {}
    found: list[LoadedFind] = []
    left, start_s, rms = [], replays.replayed_s, dict(excess)
    for scope in sorted(scopes, key=len, reverse=True):
        if any(j in f.effect.joints for f in found for j in scope):
            continue
        if replays.replayed_s - start_s >= budget_s:
            left.append((scope, max(rms.get(j, 0.0) for j in scope)))
            continue
        hints = {name: swing_fits[name, scope[0]] for name in SWING_CANDIDATES
                 if len(scope) == 1 and (name, scope[0]) in swing_fits}
        best = _best_on_scope(replays, base, base_pred, scope, until, fit, hold, progress, hints)
        if best is None:
            continue
        before, after, eff, after_hold = best
        c = BY_NAME[eff.effect]
        if not _passes(before, after) or eff.params[c.key] < _least_measured(c, robot):
            continue
        rival = _rival(replays, base, scope, until, fit, hold, progress)
        if rival is not None and rival[0] <= RIVAL_MARGIN * after_hold:
            base = rival[1]
            base_pred = _base_pred(replays, base, joints, until)
            continue
        worst = max(LOADED_PHASES, key=lambda ph: max((ww.phases[j][ph].rmse_ticks_fitted for j in scope
                                                       if ph in ww.phases[j]), default=0.0))
        found.append(LoadedFind(eff, worst, before, after))
        base.append(eff)
    # a refit keeps its effect's place in ``base``: ``effects``, then the finds in order
    n = len(effects)
    found = [f if b is f.effect else replace(f, effect=b) for f, b in zip(found, base[n:])]
    return found, [(o, r) for o, r in zip(effects, base[:n]) if r is not o], left


__all__ = ['LOADED_CANDIDATES', 'LoadedFind', 'SWING_CANDIDATES', 'search_loaded']
