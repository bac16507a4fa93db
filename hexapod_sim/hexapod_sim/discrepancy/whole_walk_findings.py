"""What the whole walk adds to a walk's findings: the check :func:`~.analysis.analyse` runs on a walk
(:func:`whole_walk_check`: the comparison, the effects it puts on every joint or on a whole leg, what the
loaded phases show, the report's notes; the searches are :mod:`.whole_walk_search`'s and
:mod:`.loaded_search`'s), and how that is carried into the analysis's findings (:mod:`.findings`):
:func:`widened`, :func:`with_refits`, :func:`whole_walk_agrees` and :func:`add_loaded`.
"""
from __future__ import annotations

import math
from dataclasses import replace

from hexapod_model.description import Effect, Robot
from hexapod_model.dictionary import BY_TERM
from hexapod_sim.discrepancy.effects import BY_NAME, scope_name
from hexapod_sim.discrepancy.findings import UNEXPLAINED_TICKS, FoundEffect
from hexapod_sim.discrepancy.loaded_search import SEARCH_BUDGET_S, LoadedFind, search_loaded
from hexapod_sim.discrepancy.recording import Recording
from hexapod_sim.discrepancy.whole_walk_search import (
    LOADED_PHASES,
    ROUNDING_RMS,
    ROUNDING_TICKS,
    SEARCH_MIN_EXPLAINED,
    SEARCH_MIN_IN_STEP_S,
    SEARCH_MIN_RATIO,
    START_S,
    SWING_PHASES,
    Replays,
    WholeWalk,
    compare,
    follows_to_rounding,
    joint_rms,
    walk_ground,
    widen,
)
from hexapod_sim.physics.terrain import Ground


def widen_to_legs(replays: Replays, effects: list, joints, progress=lambda msg: None) -> tuple[list, list]:
    """Joint effects the swings found on part of one leg that the whole walk wants on the whole leg: a
    walking coxa or tibia is read a few times a swing (4 and 5 held-out reads beside a femur's 261), so the
    swings cannot confirm an effect there; the whole walk reads them in stance too. Each such effect (of the
    list, not the servo law, not a payload) is replayed on its leg's analysed joints at its value, and kept
    there when the leg's other joints (those no other effect of one leg covers) then follow the recording by
    ``SEARCH_MIN_RATIO`` and ``SEARCH_MIN_EXPLAINED`` of their excess over rounding, and the replay stays in
    step as long (a leg's viscous damping found on its femur alone left the coxa at 0.90 ticks).
    -> (effects, [(found, widened)])."""
    rec, robot = replays.rec, replays.robot
    out, moved = list(effects), []
    res, until = replays.in_step(robot.with_effects(out), joints)
    for e in effects:
        legs = {j.leg for j in e.joints}
        if e.effect not in BY_NAME or BY_NAME[e.effect].servo_law or e.effect == 'mass_error' or len(legs) != 1:
            continue
        leg_joints = tuple(j for j in joints if j.leg in legs)
        # judged on the leg's joints no other effect of one leg covers: what such an effect leaves there is
        # not this one's (a robot-wide effect is on every joint and says nothing of where this one is)
        others = {j for x in out if x is not e and len({k.leg for k in x.joints}) == 1 for j in x.joints}
        extra = [j for j in leg_joints if j not in e.joints and j not in others]
        if not extra:
            continue
        trial = Effect(e.effect, leg_joints, dict(e.params))
        rest = [x for x in out if x is not e]
        progress(f'whole walk: {e.effect} on leg {next(iter(legs))}')
        res2, until2 = replays.in_step(robot.with_effects(rest + [trial]), joints)
        if until2 < until:
            continue
        b, a = joint_rms(rec, res, extra, until), joint_rms(rec, res2, extra, until)
        excess = b ** 2 - ROUNDING_RMS ** 2
        if (b > ROUNDING_TICKS and b / max(a, 1e-9) >= SEARCH_MIN_RATIO
                and (b ** 2 - a ** 2) / excess >= SEARCH_MIN_EXPLAINED):
            out, res, until = rest + [trial], res2, until2
            moved.append((e, trial))
    return out, moved


def widened(found: list, unexplained: list, wide: dict, whole, joints) -> tuple[list, list]:
    """Found effects of a kind the whole walk put on every joint (:func:`widen`) become one effect of the
    whole robot, judged on the whole walk (all joints and phases, nominal -> fitted); what was left
    unexplained on joints the whole walk now fits leaves the list."""
    if not wide:
        return found, unexplained
    rows = [v for row in whole.phases.values() for v in row.values()]
    n = sum(v.n_reads for v in rows)
    before = math.sqrt(sum(v.n_reads * v.rmse_ticks_nominal ** 2 for v in rows) / n) if n else math.nan
    after = math.sqrt(sum(v.n_reads * v.rmse_ticks_fitted ** 2 for v in rows) / n) if n else math.nan
    out = [f for f in found if f.effect.effect not in wide]
    out += [FoundEffect(e, scope_name(e.joints, joints), 'in the whole walk (it keeps the replay in step)', before, after)
            for e in wide.values()]

    def fitted_rms(j):
        row = whole.phases.get(j, {})
        m = sum(v.n_reads for v in row.values())
        return math.sqrt(sum(v.n_reads * v.rmse_ticks_fitted ** 2 for v in row.values()) / m) if m else math.inf

    kept = [u for u in unexplained if max(fitted_rms(j) for j in u.joints) > UNEXPLAINED_TICKS]
    return out, kept


def whole_walk_agrees(unexplained: list, whole, duration_s: float) -> list:
    """Drop what the free-leg model leaves unexplained on joints whose swings (the phases the free leg
    judges) the MuJoCo hexapod, replaying the whole walk with the effects found, follows to tick rounding
    over most of the walk: the free leg is then the model that falls short (a swing that starts while the
    leg still sheds the body's weight, the trunk moving under it), not the robot's physics. What the
    loaded phases leave is :func:`search_loaded`'s to judge: on the blocks a replay whose effects are a
    fraction of a percent off its recording's takes a touchdown elsewhere, a few ticks on any leg. A joint
    the replay judged on too few swing reads stays."""
    if whole is None:
        return unexplained

    def at_rounding(j):
        rows = [(v.n_reads, v.rmse_ticks_fitted) for ph, v in whole.phases.get(j, {}).items() if ph in SWING_PHASES]
        return follows_to_rounding(whole.in_step_until_s, duration_s, rows)

    return [u for u in unexplained if not all(at_rounding(j) for j in u.joints)]


def _refitted(e: Effect, swaps: list) -> Effect:
    """``e``, or its refitted value (``swaps``: (effect, refitted); :func:`~.loaded_search.search_loaded`)."""
    return next((n for o, n in swaps if o is e), e)


def with_refits(found: list, terms: list, swaps: list) -> tuple[list, list]:
    """The found effects and dictionary terms with the values the whole walk refitted (:func:`_refitted`)."""
    found = [replace(f, effect=_refitted(f.effect, swaps)) for f in found]
    out = []
    for t in terms:
        e = _refitted(t.effect, swaps)
        out.append(t if e is t.effect else replace(t, effect=e, words=BY_TERM[e.effect].describe(e.params)))
    return found, out


def add_loaded(found: list, blind: dict, finds, joints) -> tuple[list, dict]:
    """The effects the whole walk's loaded phases show (:func:`search_loaded`) join the found ones and
    leave the "cannot show" list on their joints."""
    found = list(found)
    for f in finds:
        e = f.effect
        found.append(FoundEffect(e, scope_name(e.joints, joints), f'in the whole walk ({f.phase.replace("_", "-")})',
                                 f.heldout_rmse_ticks_before, f.heldout_rmse_ticks_after))
        if e.effect in blind:
            rest = tuple(j for j in blind[e.effect] if j not in e.joints)
            blind = {k: v for k, v in blind.items() if k != e.effect}
            if rest:
                blind[e.effect] = rest
    return found, blind


def whole_walk_check(rec: Recording, robot: Robot, effects, ground: Ground | None, phases: dict,
                     joints, search: bool = True, progress=lambda msg: None, swing_fits: dict | None = None,
                     budget_s: float = SEARCH_BUDGET_S) -> tuple[WholeWalk, list[str], list[LoadedFind], dict, list, list]:
    """The whole-walk comparison of :func:`analyse`'s walk path, the effects found on part of the robot
    that it puts on every joint (:func:`widen`) and on a whole leg (:func:`widen_to_legs`), what
    :func:`search_loaded` finds in its loaded phases (with ``search``; ``swing_fits`` and ``budget_s`` as it
    takes them) and the effects it refits instead, and the notes for the report. ``ground``: None takes the
    recording's (``/sim/scene``), else a flat floor.
    -> (comparison, notes, loaded finds, {kind: robot-wide effect}, [(effect, on its whole leg)],
    [(effect, refitted)])."""
    ground, origin = walk_ground(rec, ground)
    fitted = robot.with_effects(effects) if effects else None
    replays = Replays(rec, robot, ground)
    ww = compare(replays, fitted, phases, joints)
    effects, wide, ww = widen(replays, list(effects), phases, joints, ww, progress)
    effects, moved = widen_to_legs(replays, effects, joints, progress)
    if moved:
        ww = compare(replays, robot.with_effects(effects), phases, joints)
    finds, refitted, left = (search_loaded(replays, list(effects), ww, progress, swing_fits, budget_s) if search
                             else ([], [], []))
    if refitted:
        effects = [_refitted(e, refitted) for e in effects]
    if finds or refitted:
        ww = compare(replays, robot.with_effects(list(effects) + [f.effect for f in finds]), phases, joints)
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
    for e, leg in moved:
        notes.append(f'whole walk: {e.effect.replace("_", " ")} found on {", ".join(map(str, e.joints))} makes the '
                     f'whole walk follow the leg\'s other joints only on the whole leg: put on leg {leg.joints[0].leg}')
    for e, n in refitted:
        ((key, v0),), ((_, v),) = e.params.items(), n.params.items()
        notes.append(f'whole walk: {e.effect.replace("_", " ")} on {", ".join(map(str, e.joints))} refitted on the '
                     f'whole walk, {key} {v0:.4g} -> {v:.4g}: at that value it explains what the loaded phases left '
                     'as well as a new effect would')
    if left:
        notes.append(f'whole walk: the loaded-phase search stopped at its budget ({budget_s:g} s of replay, '
                     '--search-budget); not searched, with their RMS error in the loaded phases: '
                     + ', '.join(f'{scope_name(sc, joints)} {v:.2f}' for sc, v in left) + ' ticks')
    for kind in wide:
        notes.append(f'whole walk: {kind.replace("_", " ")} found on part of the robot keeps the replay in step only '
                     'when it acts on every joint: put on the whole robot')
    return ww, notes, finds, wide, moved, refitted


__all__ = ['add_loaded', 'whole_walk_agrees', 'whole_walk_check', 'widen_to_legs', 'widened', 'with_refits']
