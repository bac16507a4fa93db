"""Physics outside the candidate list: a structure search over the dictionary of physical torque terms.

When the named candidates (:mod:`.fit`) leave joints unexplained, the terms of
:mod:`hexapod_model.dictionary` are fitted with the named effects in place: first a supply sag on the
whole robot, judged on every unexplained joint, then every joint term at each joint still unexplained.
Parameters are fitted on the fitting reads (a grid over physically distinct starts, then Nelder-Mead
within the plausible ranges) and judged on the held-out reads of the unexplained joints. A term is kept
when it lowers their held-out RMS error by at least ``min_ratio`` (1.5x), explains at least
``min_explained`` (75 %) of their held-out excess over tick rounding, lowers their held-out squared error
by ``min_gain_ticks2`` in all (as a list effect must: a few held-out reads confirm nothing), does not raise
the error of any other joint it touches, and no parameter sits at an end of its range. The best joint term (the largest
held-out gain) is named; where none passes alone but the best explains part, a second term is fitted
with it in place and the pair is judged together. A named list effect that touches only unexplained
joints (for the sag: any of a leg or the whole robot touching them) is the nearest candidate to the
physics there, so the terms are fitted without it first, and one that passes and leaves less than it
replaces it. With the terms found, a named list effect on part of a leg is tried on the leg's other
searched joints beside them (:func:`spread`). What stays unexplained is reported as before.

On a walk the terms the swings gave are judged on the whole walk's replay as well (:func:`choose_terms`):
a joint term the whole walk does not need is dropped, and of terms that fit the swings alike the one the
whole walk follows best is kept.
"""
from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, replace

import numpy as np
from scipy.optimize import minimize, minimize_scalar

from hexapod_model.description import Effect, Robot
from hexapod_model.dictionary import BY_TERM, TERMS, Term
from hexapod_sim.discrepancy.effects import BY_NAME
from hexapod_sim.discrepancy.hypothesis import FitSettings
from hexapod_sim.discrepancy.predict import ROUNDING_VAR, Predictor, Split, affected_joints
from hexapod_sim.discrepancy.recording import Recording
from hexapod_sim.discrepancy.simulate import Replay
from hexapod_sim.discrepancy.whole_walk_search import Replays, follows, joint_rms, walk_ground
from hexapod_sim.physics.terrain import Ground


@dataclass(frozen=True)
class FoundTerm:
    """A dictionary term that explains what the candidates left: the term (an effect of the description),
    its plain-language wording, where it shows, and the held-out RMS error of its joints without and with it."""

    effect: Effect
    scope: str
    words: str
    heldout_rmse_ticks_before: float
    heldout_rmse_ticks_after: float
    alternatives: tuple = ()         # (Effect, held-out RMS after) of the other terms that passed at its joint

    @property
    def explained(self) -> float:
        excess = self.heldout_rmse_ticks_before ** 2 - ROUNDING_VAR
        return 1.0 if excess <= 0 else (self.heldout_rmse_ticks_before ** 2 - self.heldout_rmse_ticks_after ** 2) / excess


PERIODS, PHASES = 24, 8      # an angle-periodic friction's starting periods (log-spaced) and phases


@dataclass
class SearchSettings:
    min_ratio: float = 1.5
    min_explained: float = 0.75
    # held-out squared error a term must remove [tick^2], the list's bar: a walking coxa's 18 held-out
    # reads, 0.77 -> 0.38 ticks (8 tick^2), confirm no term (a load friction there stood for a readout
    # delay the list had fitted at 2.05 ms for 2 and, by this bar, not named)
    min_gain_ticks2: float = FitSettings.min_gain_ticks2
    pair_from: float = 0.3           # a term explaining this share alone is tried with a second one
    max_evals: int = 120             # Nelder-Mead evaluations per term
    max_legs: int = 3                # joint terms on this many legs are not named (a robot-wide cause)
    # a term in place of a list effect that explains its joint but not to rounding must leave this many
    # times less than the effect does (:func:`search`'s ``doubtful``)
    doubt_margin: float = 1.3


def _starts(term: Term) -> list[tuple[float, ...]]:
    """Physically distinct starting values: stiffness x rest angle, period x phase, torque x speed."""
    if term.name == 'cable_spring':
        return list(itertools.product((0.1, 0.4, 1.2), (-1.0, 0.0, 1.0)))
    if term.name == 'periodic_friction':     # the error is many-valleyed in the period: 12 % apart
        periods = np.geomspace(0.08, 1.2, PERIODS)
        return [(0.1, float(p), ph) for p in periods for ph in np.linspace(0.0, 2.0 * math.pi, PHASES, endpoint=False)]
    if term.name == 'weak_motor':
        return list(itertools.product((0.5, 0.8, 1.2), (0.5, 0.8, 1.2)))
    return [term.start]


class _Objective:
    """Squared error of the fitting (or held-out) reads on the affected joints with a term's values."""

    def __init__(self, pred: Predictor, split: Split, meas: dict, base: tuple, term: Term, joints, affected):
        self.pred, self.split, self.meas, self.base = pred, split, meas, base
        self.term, self.joints, self.affected = term, tuple(joints), list(affected)
        self.lo = np.array([p.lo for p in term.params])
        self.hi = np.array([p.hi for p in term.params])

    def effect(self, x) -> Effect:
        x = np.clip(np.asarray(x, dtype=float), self.lo, self.hi)
        return Effect(self.term.name, self.joints, {p.key: float(v) for p, v in zip(self.term.params, x)})

    def sse(self, x, which: str = 'fit', joints=None) -> float:
        try:
            p = self.pred.predict(self.base + (self.effect(x),), self.affected)
        except ValueError:                       # e.g. a term on a leg with gear backlash: not modelled
            return math.inf
        masks = self.split.fit if which == 'fit' else self.split.hold
        out = 0.0
        for j in (joints or self.affected):
            d = (self.meas[j] - p[j])[masks[j]]
            out += float(d @ d)
        return out


def fit_term(obj: _Objective, max_evals: int, start=None) -> np.ndarray:
    """Parameters of ``obj``'s term that minimise the fitting reads' squared error (grid, then local search;
    ``start``: values it had, a start beside the grid's)."""
    term = obj.term
    if len(term.params) == 1:
        r = minimize_scalar(lambda v: obj.sse([v]), bounds=(obj.lo[0], obj.hi[0]), method='bounded',
                            options={'xatol': 1e-3 * (obj.hi[0] - obj.lo[0]), 'maxiter': 40})
        return np.array([r.x])
    cands = _starts(term) + ([tuple(start)] if start is not None else [])
    scored = sorted(zip(map(obj.sse, cands), cands), key=lambda p: p[0])[:2]     # each start scored once
    starts = [x for _, x in scored]
    best, best_f = np.asarray(starts[0], dtype=float), math.inf
    if scored[0][0] == math.inf:      # the model cannot take the term beside these effects at any value
        return best                   # (a dictionary term on a leg with gear backlash): nothing to search
    span = obj.hi - obj.lo
    for x0 in starts:
        u0 = (np.asarray(x0) - obj.lo) / span
        r = minimize(lambda u: obj.sse(obj.lo + np.clip(u, 0, 1) * span), u0, method='Nelder-Mead',
                     options={'maxfev': max_evals // 2, 'xatol': 1e-3, 'fatol': 1e-3,
                              'initial_simplex': np.vstack([u0] + [u0 + 0.1 * np.eye(len(u0))[i]
                                                                   for i in range(len(u0))])})
        if r.fun < best_f:
            best, best_f = obj.lo + np.clip(r.x, 0, 1) * span, r.fun
    return best


def _at_bound(obj: _Objective, x) -> bool:
    for p, v in zip(obj.term.params, x):
        if p.key == 'phase_rad':
            continue
        if v <= p.lo + 1e-3 * (p.hi - p.lo) or v >= p.hi - 1e-3 * (p.hi - p.lo):
            return True
    return False


def _judge(obj: _Objective, x, own, before_own: float, before_aff: dict, n_own: int, s: SearchSettings):
    """(held-out RMS of ``own`` after, gain, passes) for the term at ``x``."""
    after_own = obj.sse(x, 'hold', own)
    worse = any(obj.sse(x, 'hold', [j]) > before_aff[j] * 1.05 + 1.0 for j in obj.affected if j not in own)
    rb, ra = math.sqrt(before_own / n_own), math.sqrt(after_own / n_own)
    excess = rb ** 2 - ROUNDING_VAR
    explained = (rb ** 2 - ra ** 2) / excess if excess > 0 else 0.0
    ok = (rb / max(ra, 1e-9) >= s.min_ratio and explained >= s.min_explained
          and before_own - after_own >= s.min_gain_ticks2 and not worse and not _at_bound(obj, x))
    return ra, before_own - after_own, ok, explained


def search(replay: Replay, robot: Robot, split: Split, named: tuple, joints, scope_name,
           settings: SearchSettings | None = None, doubtful=()) -> tuple[list[FoundTerm], list[Effect]]:
    """Dictionary terms that explain what ``named`` (the accepted list effects) leaves on ``joints``, and the
    named effects they displace: a list effect only on unexplained joints is the nearest candidate to the
    physics there (load-proportional friction was fitted as viscous damping, leaving 1.2 ticks), so terms
    are also fitted without it, and one that passes without it and leaves less than it does replaces it.
    On the ``doubtful`` joints (of ``joints``: explained by a list effect of their own, but not to
    rounding) a term is only tried in place of that effect, and replaces it where it leaves at most
    1 / ``doubt_margin`` of what the effect leaves."""
    s = settings or SearchSettings()
    pred = Predictor(replay, robot, workers=1)
    meas = {j: replay.reads[j].tick for j in replay.joints}
    base = tuple(named)
    found: list[FoundTerm] = []
    displaced: list[Effect] = []
    beat_a_rival: list[FoundTerm] = []      # terms that replaced a named list effect on their joints
    todo = [j for j in joints if j in replay.reads]
    unexplained = [j for j in todo if j not in doubtful]
    base, sag, gone = _supply_sag(pred, split, meas, base, named, unexplained, s)
    if sag:
        _g, _ok, _e, obj, x, own, rb, ra = sag
        e = obj.effect(x)
        base = base + (e,)
        found.append(FoundTerm(e, scope_name(e.joints, replay.joints), BY_TERM[e.effect].describe(e.params), rb, ra))
        displaced.extend(gone)
        todo = [a for a in todo if a not in own]
    while todo:
        j = todo[0]
        rivals = tuple(e for e in base if e in named and j in e.joints and set(e.joints) <= set(todo))
        chosen, won = [], False
        if rivals:               # first without them: where they are the nearest candidate, that is the answer
            without = tuple(e for e in base if e not in rivals)
            alt = _round(pred, split, meas, without, j, todo, s)
            margin = s.doubt_margin if j in doubtful else 1.0
            if alt and alt[-1][7] * margin < _current(pred, split, meas, base, alt[-1][5]):
                chosen, base, won = alt, without, True
                displaced.extend(rivals)
        if not chosen and j not in doubtful:
            chosen = _round(pred, split, meas, base, j, todo, s)
        if not chosen:
            todo.pop(0)
            continue
        alts = tuple((r[3].effect(r[4]), r[7]) for r in chosen[0][8]) if len(chosen) == 1 else ()
        for gain, ok, expl, obj, x, own, rb, ra, *_ in chosen:
            e = obj.effect(x)
            base = base + (e,)
            found.append(FoundTerm(e, scope_name(e.joints, replay.joints), BY_TERM[e.effect].describe(e.params), rb, ra,
                                   alts))
            if won:
                beat_a_rival.append(found[-1])
        done = {a for r in chosen for a in r[5]}
        todo = [a for a in todo if a not in done]
    return on_few_legs(found, beat_a_rival, s.max_legs), displaced


def on_few_legs(found: list[FoundTerm], beat_a_rival: list[FoundTerm], max_legs: int) -> list[FoundTerm]:
    """``found`` without its joint terms where those are on ``max_legs`` legs or more: separate joint physics
    on half the robot at once is less likely than one robot-wide cause no term captures (a walk sagging far
    below the supply gave weak motors and load friction on 12 joints). A term that replaced a named list
    effect on its joints (``beat_a_rival``) was judged against that effect there; it is not counted and
    stays (a femur's load friction, 32.7 -> 0.26 ticks where the list's viscous damping left 0.71, beside
    small leftovers of a motor damping on four other legs)."""
    legs = {j.leg for t in found if not BY_TERM[t.effect.effect].robot_wide and t not in beat_a_rival
            for j in t.effect.joints}
    if len(legs) < max_legs:
        return found
    return [t for t in found if BY_TERM[t.effect.effect].robot_wide or t in beat_a_rival]


def refit(replay: Replay, robot: Robot, split: Split, named: tuple, terms: list, scope_name,
          settings: SearchSettings | None = None, pred: Predictor | None = None) -> list[FoundTerm]:
    """``terms`` (found by :func:`search`) fitted again in turn with ``named`` and the other terms in place
    (from the values they had), with their joints' held-out RMS error without and with them (``pred``: a
    predictor of ``replay`` and ``robot`` whose cache to use)."""
    s = settings or SearchSettings()
    pred = pred or Predictor(replay, robot, workers=1)
    meas = {j: replay.reads[j].tick for j in replay.joints}
    out = list(terms)
    for i, t in enumerate(out):
        e = t.effect
        term = BY_TERM[e.effect]
        base = tuple(named) + tuple(u.effect for k, u in enumerate(out) if k != i)
        aff = sorted(affected_joints(term.name, e.joints) & set(replay.joints))
        obj = _Objective(pred, split, meas, base, term, e.joints, aff)
        new = obj.effect(fit_term(obj, s.max_evals, [e.params[p.key] for p in term.params]))
        own = [j for j in e.joints if j in replay.reads]
        out[i] = replace(t, effect=new, scope=scope_name(new.joints, replay.joints), words=term.describe(new.params),
                         heldout_rmse_ticks_before=_current(pred, split, meas, base, own),
                         heldout_rmse_ticks_after=_current(pred, split, meas, base + (new,), own))
    return out


def spread(replay: Replay, robot: Robot, split: Split, named: tuple, terms: list, joints, scope_name,
           settings: SearchSettings | None = None) -> tuple[list[tuple[Effect, Effect]], list[FoundTerm]]:
    """A named list effect (not a servo-law term) tried on the other joints of its legs that the
    dictionary searched (``joints``), at its value, with the terms on that leg fitted again beside it: a
    term can hide the list effect on its joint when the list's fit there was swamped by the physics the
    term stands for (a one-leg stand whose femur carries a cable spring: the robot-wide torque limit was
    named on the coxa only, load friction on the tibia). A joint takes the effect where its held-out RMS
    error falls below 1 / ``doubt_margin`` of what it is and the leg's held-out squared error falls; a term
    on it that then removes less than ``min_gain_ticks2`` is dropped. -> ((effect, widened) pairs, terms)."""
    s = settings or SearchSettings()
    pred = Predictor(replay, robot, workers=1)
    meas = {j: replay.reads[j].tick for j in replay.joints}
    named, terms, moved = list(named), list(terms), []
    todo = [j for j in joints if j in replay.reads]
    for i in range(len(named)):
        first = named[i]
        if BY_NAME[first.effect].servo_law:
            continue
        for k in [j for j in todo if j.leg in {a.leg for a in named[i].joints} and j not in named[i].joints]:
            wide = replace(named[i], joints=tuple(j for j in replay.joints if j in named[i].joints or j == k))
            trial = named[:i] + [wide] + named[i + 1:]
            leg = [j for j in replay.joints if j.leg == k.leg]
            mine = [t for t in terms if any(j.leg == k.leg for j in t.effect.joints)]
            rest = tuple(t.effect for t in terms if t not in mine)
            ref = refit(replay, robot, split, tuple(trial) + rest, mine, scope_name, s, pred)
            tried = [t for t in ref if not _idle(pred, split, meas, tuple(trial) + rest
                                                 + tuple(u.effect for u in ref if u is not t), t, k, s)]
            now = tuple(named) + tuple(t.effect for t in terms)
            then = tuple(trial) + rest + tuple(t.effect for t in tried)
            if (_current(pred, split, meas, then, [k]) * s.doubt_margin < _current(pred, split, meas, now, [k])
                    and _current(pred, split, meas, then, leg) < _current(pred, split, meas, now, leg)):
                named[i] = wide
                terms = [t for t in terms if t not in mine] + tried
        if named[i] is not first:
            moved.append((first, named[i]))
    return moved, terms


def _idle(pred, split, meas, base, term: FoundTerm, k, s: SearchSettings) -> bool:
    """Whether ``term``, on joint ``k``, removes less than ``min_gain_ticks2`` of its joints' held-out squared
    error beside ``base``."""
    if k not in term.effect.joints:
        return False
    own = [j for j in term.effect.joints if j in meas]
    without, _ = _held_out_sse(pred, split, meas, base, own)
    return without - _held_out_sse(pred, split, meas, base + (term.effect,), own)[0] < s.min_gain_ticks2


def _supply_sag(pred, split, meas, base, named, todo, s: SearchSettings):
    """The supply sag on the whole robot, judged on every unexplained joint: first without the named
    effects of a leg or the whole robot that touch them (a torque limit is the list's nearest candidate to a
    sag; fitted over it, the sag cannot pass), then over them. Returns (base, result or None, displaced)."""
    if not todo:
        return base, None, ()
    wide = tuple(e for e in named if len(e.joints) > 1 and set(e.joints) & set(todo))
    # a rival is displaced only if the sag leaves less on every joint the rival explains, not only on the
    # unexplained ones (1.33x motor damping took a walk's 18 joints 2.43 -> 0.40 ticks; the sag replaced
    # it on the few joints left above 0.6 and left the others at 1-2 ticks)
    cover = sorted(set(todo) | {a for e in wide for a in e.joints if a in pred.rep.reads})
    term = BY_TERM['supply_sag']
    joints = tuple(pred.rep.joints)
    for rivals in ((wide, ()) if wide else ((),)):
        b = tuple(e for e in base if e not in rivals)
        obj = _Objective(pred, split, meas, b, term, joints, joints)
        p0 = pred.predict(b, joints)
        before = {a: float(((meas[a] - p0[a])[split.hold[a]]) @ ((meas[a] - p0[a])[split.hold[a]])) for a in joints}
        n_own = sum(int(np.count_nonzero(split.hold[a])) for a in todo)
        if n_own == 0:
            break
        x = fit_term(obj, s.max_evals)
        ra, gain, ok, expl = _judge(obj, x, list(todo), sum(before[a] for a in todo), before, n_own, s)
        if ok and (not rivals or _current(pred, split, meas, b + (obj.effect(x),), cover)
                   < _current(pred, split, meas, base, cover)):
            return b, (gain, ok, expl, obj, x, list(todo), math.sqrt(sum(before[a] for a in todo) / n_own), ra), rivals
    return base, None, ()


def _held_out_sse(pred, split, meas, base, own) -> tuple[float, int]:
    """(squared error, number) of the held-out reads of ``own`` with the effects ``base``."""
    p = pred.predict(base, own)
    d = np.concatenate([(meas[a] - p[a])[split.hold[a]] for a in own])
    return float(d @ d), len(d)


def _current(pred, split, meas, base, own) -> float:
    """Held-out RMS error of ``own`` with the effects ``base``."""
    sse, n = _held_out_sse(pred, split, meas, base, own)
    return math.sqrt(sse / max(n, 1))


def _round(pred, split, meas, base, j, todo, s: SearchSettings):
    """Every joint term fitted at joint ``j`` over ``base``: the passing one with the largest held-out gain
    (with the other passing ones as its last item: the whole walk may tell them apart), or a passing pair,
    or nothing."""
    replay = pred.rep
    results = []
    for term, on in ((BY_TERM[t.name], (j,)) for t in TERMS if not t.robot_wide):
        own = [j]
        aff = sorted(affected_joints(term.name, on) & set(replay.joints))
        obj = _Objective(pred, split, meas, base, term, on, aff)
        p0 = pred.predict(base, aff)
        before_aff = {a: float(((meas[a] - p0[a])[split.hold[a]]) @ ((meas[a] - p0[a])[split.hold[a]])) for a in aff}
        n_own = sum(int(np.count_nonzero(split.hold[a])) for a in own)
        if n_own == 0:
            continue
        before_own = sum(before_aff[a] for a in own)
        x = fit_term(obj, s.max_evals)
        ra, gain, ok, expl = _judge(obj, x, own, before_own, before_aff, n_own, s)
        results.append((gain, ok, expl, obj, x, own, math.sqrt(before_own / n_own), ra))
    results.sort(key=lambda r: -r[0])
    passing = [r for r in results if r[1]]
    if passing:
        return [passing[0] + (passing[1:],)]
    if results and results[0][2] >= s.pair_from:
        return _pair(pred, split, meas, base, results[0], j, s)
    return []


def _pair(pred, split, meas, base, first, j, s: SearchSettings):
    """The best term with a second one on the same joint, fitted with it in place; both or nothing."""
    _g, _ok, _e, obj1, x1, own, rb, _ra = first
    e1 = obj1.effect(x1)
    best = None
    for t in TERMS:
        if t.robot_wide or t.name == e1.effect:
            continue
        aff = sorted(affected_joints(t.name, (j,)) & set(pred.rep.joints))
        obj2 = _Objective(pred, split, meas, base + (e1,), t, (j,), aff)
        x2 = fit_term(obj2, s.max_evals)
        n_own = sum(int(np.count_nonzero(split.hold[a])) for a in own)
        ra = math.sqrt(obj2.sse(x2, 'hold', own) / n_own)
        excess = rb ** 2 - ROUNDING_VAR
        ok = (rb / max(ra, 1e-9) >= s.min_ratio and excess > 0 and (rb ** 2 - ra ** 2) / excess >= s.min_explained
              and n_own * (rb ** 2 - ra ** 2) >= s.min_gain_ticks2 and not _at_bound(obj2, x2) and not _at_bound(obj1, x1))
        if ok and (best is None or ra < best[1]):
            best = (obj2, ra, x2)
    if best is None:
        return []
    obj2, ra, x2 = best
    n_own = sum(int(np.count_nonzero(split.hold[a])) for a in own)
    ra1 = math.sqrt(obj1.sse(x1, 'hold', own) / n_own)
    return [(0.0, True, 0.0, obj1, x1, own, rb, ra1), (0.0, True, 0.0, obj2, x2, own, ra1, ra)]


def choose_terms(rec: Recording, robot: Robot, named: list, terms: list, ground: Ground | None, phases: dict,
                 joints, progress=lambda msg: None) -> tuple[list, list[str]]:
    """The dictionary terms of a walk's swings, judged on the whole walk (the named effects and the other
    terms in place). A joint term the whole walk does not need (without it the replay follows its joints
    to tick rounding in every phase over most of the walk: what the free leg missed there is the free-leg
    model's, as in :func:`.whole_walk_search.follows`) is dropped. A term found where others passed as well
    (:attr:`FoundTerm.alternatives`; a weaker motor and friction that grows with the gear load
    slow a swinging leg alike, but only the friction holds a leg that carries the body) is replayed with
    each of them, and the one whose joints follow the recording best, over the span the best replay stays
    in step, is kept. -> (terms, notes)."""
    joint_terms = [t for t in terms if not BY_TERM[t.effect.effect].robot_wide]
    if not joint_terms:
        return list(terms), []
    ground, _ = walk_ground(rec, ground)
    replays = Replays(rec, robot, ground)
    joints = [j for j in joints if j in rec.states]
    out, notes = list(terms), []
    for t in joint_terms:
        k = next(i for i, u in enumerate(out) if u is t)
        others = list(named) + [u.effect for u in out if u is not t]
        progress(f'whole walk: without {t.effect.effect} on {", ".join(map(str, t.effect.joints))}')
        res, until = replays.in_step(robot.with_effects(others), joints)
        if follows(rec, res, until, phases, t.effect.joints):
            notes.append(f'whole walk: without {t.words} on {", ".join(map(str, t.effect.joints))} the replay follows '
                         'the recording there to tick rounding in every phase: the free leg missed it, not the robot')
            out.pop(k)
            continue
        if not t.alternatives:
            continue
        options = [(t.effect, t.heldout_rmse_ticks_after)] + list(t.alternatives)
        runs = []
        for e, _ra in options:
            progress(f'whole walk: {e.effect} on {", ".join(map(str, e.joints))}')
            runs.append(replays.in_step(robot.with_effects(others + [e]), joints))
        until = max(u for _, u in runs)
        scores = [joint_rms(rec, res, t.effect.joints, until) for res, _ in runs]
        best = int(np.argmin(scores))
        if best:
            e, ra = options[best]
            out[k] = replace(t, effect=e, words=BY_TERM[e.effect].describe(e.params), heldout_rmse_ticks_after=ra,
                             alternatives=tuple(o for i, o in enumerate(options) if i != best))
            notes.append(f'whole walk: {e.effect.replace("_", " ")} and {t.effect.effect.replace("_", " ")} fit the '
                         f'swings of {", ".join(map(str, e.joints))} alike; the whole walk follows the recording with '
                         f'{e.effect.replace("_", " ")} ({scores[best]:.2f} ticks RMS against {scores[0]:.2f})')
    return out, notes


__all__ = ['FoundTerm', 'SearchSettings', 'choose_terms', 'fit_term', 'on_few_legs', 'refit', 'search']
