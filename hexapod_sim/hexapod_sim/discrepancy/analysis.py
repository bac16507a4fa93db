"""The whole analysis: simulate, locate, name and fit, then before/after on held-out data (step 4).

:func:`analyse` is the library entry point of the ``discrepancy`` tool; it takes a
:class:`~.recording.Recording` (not a path) and a robot, so tests and the benchmark call it the
way the command-line tool does.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, replace

import numpy as np

from hexapod_model.description import Effect, Robot, load_robot
from hexapod_model.joints import Joint
from hexapod_sim.discrepancy import structure
from hexapod_sim.discrepancy.effects import BY_NAME, scope_name
from hexapod_sim.discrepancy.findings import DOUBTFUL_TICKS, UNEXPLAINED_TICKS, FoundEffect, JointFit, PhaseFit, Unexplained
from hexapod_sim.discrepancy.fit import TWIN_OF, FitSettings, Hypothesis, Namer, law_of_twins, uneven_parts
from hexapod_sim.discrepancy.loaded_search import SEARCH_BUDGET_S
from hexapod_sim.discrepancy.locate import Mismatch, dominant_condition, mismatch_windows, read_conditions
from hexapod_sim.discrepancy.predict import ROUNDING_VAR, Predictor, make_split, unobservable
from hexapod_sim.discrepancy.recording import Recording
from hexapod_sim.discrepancy.segments import PHASES, gait_phases, replay_analysed
from hexapod_sim.discrepancy.simulate import Replay
from hexapod_sim.discrepancy.whole_walk_findings import add_loaded, whole_walk_agrees, whole_walk_check, widened, with_refits

MODES = ('auto', 'stand', 'walk')

@dataclass
class Analysis:
    source: str
    mode: str
    robot: Robot
    replay: Replay
    split: object
    duration_s: float
    residual_before: dict
    residual_after: dict
    conditions: dict
    mismatches: list[Mismatch]
    effects: list[FoundEffect]
    joints: dict[Joint, JointFit]
    notes: list[str] = field(default_factory=list)
    runtime_s: float = 0.0
    log: list = field(default_factory=list)
    glitches: tuple = ()             # samples left out as physically impossible (recording.glitches)
    # walks: per joint and gait phase (segments.PHASES) -> PhaseFit over the analysed reads
    phase_fit: dict = field(default_factory=dict)
    # candidate effect -> analysed joints on which the recording cannot show it (predict.unobservable)
    blind: dict = field(default_factory=dict)
    min_drop_ticks: float = 0.0      # held-out RMS drop an effect had to reach (the "cannot show" bound)
    min_gain_ticks2: float = 0.0     # and held-out squared-error gain (predict.can_confirm)
    unexplained: list = field(default_factory=list)   # Unexplained: what no candidate explains
    # walks: the whole walk replayed on the MuJoCo hexapod, nominal and with the effects (whole_walk_search.WholeWalk)
    whole_walk: object | None = None
    terms: list = field(default_factory=list)         # structure.FoundTerm: dictionary terms outside the list

    @property
    def found(self) -> tuple[Effect, ...]:
        return tuple(f.effect for f in self.effects) + tuple(t.effect for t in self.terms)


def _rmse(res: dict, masks: dict, joints) -> tuple[float, int]:
    sse, n = 0.0, 0
    for j in joints:
        if j in res:
            r = res[j][masks[j]]
            sse += float(r @ r)
            n += len(r)
    return (math.sqrt(sse / n) if n else math.nan), n


def _explained(f: FoundEffect) -> float:
    """Share of its joints' held-out excess over tick rounding that a found effect explains."""
    excess = f.heldout_rmse_ticks_before ** 2 - ROUNDING_VAR
    if not excess > 0:
        return 1.0
    return (f.heldout_rmse_ticks_before ** 2 - f.heldout_rmse_ticks_after ** 2) / excess


def _unexplained(replay: Replay, split, cond: dict, res1: dict, jfit: dict, nearest) -> list[Unexplained]:
    """The judged joints the named effects leave above :data:`UNEXPLAINED_TICKS`, one entry per nearest
    candidate that was tried and not named (its joints), else per joint; with where the rest shows."""
    left = [j for j, v in jfit.items() if v.n_heldout > 0 and v.heldout_rmse_ticks_after > UNEXPLAINED_TICKS]
    zero = {j: np.zeros_like(res1[j]) for j in left}
    out, done = [], set()
    for f, h in nearest:
        js = tuple(j for j in f.effect.joints if j in left)
        if not js:
            continue
        rmse, _ = _rmse(res1, split.hold, js)
        out.append(Unexplained(js, dominant_condition(js, cond, res1, zero), rmse, f.effect,
                               f.heldout_rmse_ticks_after))
        done.update(js)
    for j in left:
        if j not in done:
            out.append(Unexplained((j,), dominant_condition((j,), cond, res1, zero), jfit[j].heldout_rmse_ticks_after))
    return out


def _doubtful(found, jfit: dict, unexplained) -> list:
    """The joints a list effect of their own (one joint, no servo-law term) explains but leaves above
    :data:`DOUBTFUL_TICKS` held out, and no unexplained entry lists."""
    left = {j for u in unexplained for j in u.joints}
    return [f.effect.joints[0] for f in found
            if len(f.effect.joints) == 1 and not BY_NAME[f.effect.effect].servo_law and f.effect.joints[0] not in left
            and f.effect.joints[0] in jfit and jfit[f.effect.joints[0]].heldout_rmse_ticks_after > DOUBTFUL_TICKS]


def _outside_the_list(replay: Replay, robot: Robot, split, cond, effects, found, unexplained, res1, jfit, nearest,
                      settings: FitSettings, step, choose=None):
    """The dictionary's structure search (:mod:`.structure`) on the joints the named effects leave
    unexplained, and in place of a list effect that leaves its joint above rounding (:func:`_doubtful`);
    returns the terms found, the named effects they leave (a list effect a term displaced is
    dropped), and the unexplained list, residuals and joint fits with them. ``choose(effects, terms)``
    (a walk: :func:`~.structure.choose_terms`) picks between terms the swings fit alike."""
    doubtful = _doubtful(found, jfit, unexplained)
    if not (unexplained or doubtful) or not settings.dictionary:
        return [], found, unexplained, res1, jfit
    step('searching the dictionary of physical terms')
    joints = list(dict.fromkeys([j for u in unexplained for j in u.joints] + doubtful))
    terms, displaced = structure.search(replay, robot, split, tuple(effects), joints, scope_name,
                                        _search_settings(settings), doubtful=tuple(doubtful))
    law_first = not terms and not effects
    if law_first:
        terms = _terms_beside_a_servo_law(replay, robot, split, settings, joints, step)
    if not terms:
        return [], found, unexplained, res1, jfit
    found = [f for f in found if f.effect not in displaced]
    effects = [e for e in effects if e not in displaced]
    if choose is not None:
        terms = choose(effects, terms)
    effects, found, terms = _servo_law_beside(replay, robot, split, cond, settings, effects, found, terms, step)
    if law_first and not found:          # the terms were found beside a servo-law term that is not confirmed
        return [], found, unexplained, res1, jfit
    found, terms = _twins_as_servo_law(replay, robot, split, cond, settings, found, terms, step)
    pred = Predictor(replay, robot, workers=1)
    found, terms = _beside_the_terms(pred, replay, robot, split, cond, settings, found, terms, joints, step)
    return (terms, found) + _judged_with(replay, robot, split, cond, [f.effect for f in found] + [t.effect for t in terms],
                                         jfit, nearest, pred)


def _judged_with(replay: Replay, robot: Robot, split, cond, effects, jfit, nearest, pred: Predictor | None = None):
    """(unexplained, residuals, joint fits) with ``effects`` in place (``pred``: a predictor whose cache to use)."""
    pred = pred or Predictor(replay, robot, workers=1)
    res1 = replay.residuals(pred.predict(tuple(effects), replay.joints))
    jfit = {j: JointFit(v.heldout_rmse_ticks_before, _rmse(res1, split.hold, [j])[0], v.n_heldout)
            for j, v in jfit.items()}
    return _unexplained(replay, split, cond, res1, jfit, nearest), res1, jfit


def _rejudged(pred: Predictor, replay: Replay, split, cond, found, terms, moved) -> list:
    """``found`` with each effect of ``moved`` ((effect, widened) pairs) widened, and judged on the held-out
    reads of its joints as :func:`_found_effects` judges (its condition kept)."""
    out = [replace(f, effect=next((n for o, n in moved if o is f.effect), f.effect)) for f in found]
    every = [f.effect for f in out] + [t.effect for t in terms]
    pred_w = pred.predict(every, replay.joints)
    for i, f in enumerate(out):
        e = f.effect
        if any(n is e for _, n in moved):
            c = BY_NAME[e.effect]
            (judged,) = _found_effects(pred, replay, split, cond, [e], [Hypothesis(c, e.joints, value=e.params[c.key])],
                                       None, pred_w, [x for x in every if x is not e])
            out[i] = replace(judged, condition=f.condition)
    return out


def _beside_the_terms(pred: Predictor, replay: Replay, robot: Robot, split, cond, settings: FitSettings, found,
                      terms, joints, step) -> tuple[list, list]:
    """The named list effects tried on the other joints of their legs beside the terms
    (:func:`~.structure.spread`); -> (found, terms), the widened effects judged again (with ``pred``)."""
    step('the named effects beside the terms on the rest of their legs')
    moved, terms = structure.spread(replay, robot, split, tuple(f.effect for f in found), terms, joints, scope_name,
                                    _search_settings(settings))
    if not moved:
        return found, terms
    return _rejudged(pred, replay, split, cond, found, terms, moved), terms


def _on_whole_legs(replay: Replay, robot: Robot, split, cond, phases, found, terms, moved, res0, jfit, nearest):
    """The findings with the effects the whole walk put on their whole leg (``moved``: (effect, widened);
    :func:`~.whole_walk_findings.widen_to_legs`), each judged on the held-out reads of its leg as
    :func:`_found_effects` judges (its condition kept), and what they leave. -> (found, unexplained,
    residuals, joint fits, phase table)."""
    pred = Predictor(replay, robot, workers=1)
    out = _rejudged(pred, replay, split, cond, found, terms, moved)
    every = [f.effect for f in out] + [t.effect for t in terms]
    unexplained, res1, jfit = _judged_with(replay, robot, split, cond, every, jfit, nearest, pred)
    _, phase_fit = _locate_phases(replay, phases, [], res0, res1)
    return out, unexplained, res1, jfit, phase_fit


def _twins_as_servo_law(replay: Replay, robot: Robot, split, cond, settings: FitSettings, found, terms,
                        step) -> tuple[list, list]:
    """Joint effects named on several joints that are the twin of a servo-law term (readout delays of a
    goal latency, viscous damping of a motor damping; :data:`~.fit.TWIN_OF`), where no servo-law term is
    named and the dictionary found terms: the servo law is searched beside the terms with the twins taken
    out (:func:`_servo_law_beside`), and the term it names replaces them where it gains at least
    ``parsimony`` of what they gain on the held-out reads. A term can hide the servo-law term on its joint,
    and then the twin wins on the others one by one (a 2 ms goal latency on a one-leg stand with a weaker
    tibia motor was named as 2 ms readout delays of its coxa and femur). -> (found, terms)."""
    twins = [f for f in found if f.effect.effect in TWIN_OF.values()]
    if len(twins) < 2 or not terms or any(BY_NAME[f.effect.effect].servo_law for f in found):
        return found, terms
    rest = [f for f in found if f not in twins]
    effects, law_found, law_terms = _servo_law_beside(replay, robot, split, cond, settings, [f.effect for f in rest],
                                                      rest, terms, step)
    if len(law_found) == len(rest):
        # the terms took the servo law's share on their joints (a weaker tibia motor fitted 0.54 of the
        # no-load speed for 0.69 beside 1.28x motor damping, named as 0.057 N m s/rad of viscous damping on
        # the coxa and the femur): fitted again beside the servo-law term the twins stand for
        twins_law = law_of_twins([f.effect for f in twins], robot, replay.joints)
        step('the terms again beside the servo law the twins stand for')
        refitted = structure.refit(replay, robot, split, tuple(f.effect for f in rest) + (twins_law,), terms,
                                   scope_name, _search_settings(settings))
        effects, law_found, law_terms = _servo_law_beside(replay, robot, split, cond, settings,
                                                          [f.effect for f in rest], rest, refitted, step)
        if len(law_found) == len(rest):
            return found, terms
    pred = Predictor(replay, robot, workers=1)

    def sse(effs):
        r, n = _rmse(replay.residuals(pred.predict(tuple(effs), replay.joints)), split.hold, replay.joints)
        return r * r * n

    base = sse([f.effect for f in rest] + [t.effect for t in terms])
    with_twins = sse([f.effect for f in found] + [t.effect for t in terms])
    with_law = sse(list(effects) + [t.effect for t in law_terms])
    if base - with_law < settings.parsimony * (base - with_twins):
        return found, terms
    return law_found, law_terms


def _search_settings(settings: FitSettings) -> structure.SearchSettings:
    """The dictionary search's settings with the namer's bar on the held-out gain."""
    return structure.SearchSettings(min_gain_ticks2=settings.min_gain_ticks2)


def _servo_law_candidates(settings: FitSettings) -> tuple[str, ...]:
    return tuple(c for c in settings.candidates if BY_NAME[c].servo_law)


def _terms_beside_a_servo_law(replay: Replay, robot: Robot, split, settings: FitSettings, joints, step) -> list:
    """Where neither the list nor the dictionary explains anything: the dictionary's terms found beside the
    servo-law term that improves the recording most (held-out ratio and drop, whatever share it explains),
    for :func:`_servo_law_beside` to confirm. A servo-law term spreads over every joint, so beside it no
    term explains enough of a joint alone (a femur's angle-periodic friction beside 0.09 N m more punch on
    a one-leg stand left the whole leg at 1.4 ticks, nothing named)."""
    law = _servo_law_candidates(settings)
    if not law:
        return []
    step('the dictionary beside the servo law')
    namer = Namer(replay, robot, split, replace(settings, candidates=law, max_effects=1, min_explained=0.0),
                  workers=1)
    try:
        tentative, _ = namer.run()
    finally:
        namer.close()
    if not tentative:
        return []
    terms, _ = structure.search(replay, robot, split, tuple(tentative), joints, scope_name, _search_settings(settings))
    return terms


def _servo_law_beside(replay: Replay, robot: Robot, split, cond, settings: FitSettings, effects, found, terms,
                      step) -> tuple[list, list, list]:
    """The servo law's terms searched again with the dictionary's terms in place, where none was named: a
    robot-wide term explains too little of a joint that also carries a term the list lacks (0.09 N m
    more punch beside a femur's angle-periodic friction on a one-leg stand: punch alone 1.39 -> 1.08 ticks
    held out, 42 % of the excess, and no joint effect of the list passes beside it). Named as the namer
    names (held-out acceptance, and ``min_final_explained`` of its joints' excess with the rest in place).
    Where the term found explains too little, the terms are fitted again with it in place and it is
    searched once more: fitted first, a term takes part of the servo law's share (a tibia's cable spring
    beside 0.044 N m more punch left the punch 0.030, 71 % of its joints' excess).
    -> (effects, found, terms) with it."""
    law = _servo_law_candidates(settings)
    if not terms or not law or any(BY_NAME[e.effect].servo_law for e in effects):
        return effects, found, terms
    step('the servo law beside the terms found')
    namer = Namer(replay, robot, split, replace(settings, candidates=law, max_effects=1), workers=1)
    original = terms            # kept where no servo-law term is named
    try:
        for turn in range(2):
            given = tuple(effects) + tuple(t.effect for t in terms)
            more, accepted = namer.run(given=given)
            if not more:
                break
            pred_w = namer.pred.predict(given + tuple(more), replay.joints)
            # given holds the terms, so no effect is judged against the nominal prediction (pred0: None)
            new = [f for f in _found_effects(namer.pred, replay, split, cond, more, accepted, None, pred_w, given)
                   if _explained(f) >= settings.min_final_explained]
            if new:
                return list(effects) + [f.effect for f in new], list(found) + new, terms
            if turn:
                break
            step('the terms again beside the servo law')
            terms = structure.refit(replay, robot, split, tuple(effects) + tuple(more), terms, scope_name,
                                    _search_settings(settings))
            if not all(t.explained >= structure.SearchSettings.min_explained for t in terms):
                break
    finally:
        namer.close()
    return effects, found, original


def _locate_phases(replay: Replay, phases: dict, mism: list, res0: dict, res1: dict):
    """Walks: the gait phase of every mismatch window, and the residual per joint and phase."""
    labels = {j: phases[j.leg].label(replay.reads[j].t_s) for j in replay.joints}
    out = []
    for m in mism:
        t = replay.reads[m.joint].t_s
        sel = labels[m.joint][(t >= m.t_start) & (t <= m.t_end)]
        ph = PHASES[int(np.bincount(sel, minlength=len(PHASES)).argmax())] if len(sel) else ''
        out.append(replace(m, phase=ph))
    table = {}
    for j in replay.joints:
        row = {}
        for k, name in enumerate(PHASES):
            sel = labels[j] == k
            n = int(np.count_nonzero(sel))
            if n:
                row[name] = PhaseFit(n, float(np.sqrt(np.mean(res0[j][sel] ** 2))),
                                     float(np.sqrt(np.mean(res1[j][sel] ** 2))))
        table[j] = row
    return out, table


def _progress_bar(progress: bool):
    """(bar or None, step(msg)): a tqdm bar advanced by each step of the analysis, when asked for."""
    bar = None
    if progress:
        from tqdm import tqdm
        bar = tqdm(total=None, desc='discrepancy', unit=' step', leave=False, disable=None)

    def step(msg: str):
        if bar is not None:
            bar.set_postfix_str(msg[:60])
            bar.update(1)
    return bar, step


def _found_effects(pred: Predictor, replay: Replay, split, cond: dict, effects: list, accepted: list,
                   pred0: dict | None, pred1: dict, given=()) -> list[FoundEffect]:
    """Each accepted effect with its joints' held-out RMS error without it (the others and ``given`` in
    place) and with it."""
    found = []
    for i, h in enumerate(accepted):
        others = list(given) + [e for k, e in enumerate(effects) if k != i]
        p_wo = pred.predict(others, replay.joints) if others else pred0
        own = [j for j in h.joints if j in replay.reads]
        r_wo = {j: replay.reads[j].tick - p_wo[j] for j in own}
        r_w = {j: replay.reads[j].tick - pred1[j] for j in own}
        b, _ = _rmse(r_wo, split.hold, own)
        a, _ = _rmse(r_w, split.hold, own)
        found.append(FoundEffect(h.effect, scope_name(h.joints, replay.joints),
                                 dominant_condition(own, cond, r_wo, r_w), b, a))
    return found


def _shown(blind: dict, found: list) -> dict:
    """``blind`` without the joints where an effect was found: what was found was shown (a typical
    magnitude may not show where a larger one does)."""
    for f in found:
        if f.effect.effect in blind:
            rest = tuple(j for j in blind[f.effect.effect] if j not in f.effect.joints)
            blind = {k: v for k, v in blind.items() if k != f.effect.effect}
            if rest:
                blind[f.effect.effect] = rest
    return blind


def _name_effects(replay: Replay, robot: Robot, split, settings: FitSettings, pred0: dict, cond: dict, step,
                  workers: int):
    """Name and fit the candidate effects (:class:`~.fit.Namer`) and judge them on the held-out reads.
    -> (effects named, found effects, (found, hypothesis) of those too weak to name, unobservable, prediction)."""
    namer = Namer(replay, robot, split, settings, progress=step, workers=workers)
    try:
        blind = unobservable(namer.pred, split, pred0, settings.candidates, settings.min_drop_ticks,
                             settings.min_gain_ticks2)
        effects, accepted = namer.run()
        # a small part of a larger effect is that effect fitted unevenly (fit.UNEVEN_SHARE): not named, and
        # the rest fitted again without it
        uneven = uneven_parts(effects, robot)
        if uneven:
            accepted = namer.refine([h for i, h in enumerate(accepted) if i not in uneven])
        accepted = namer.servo_law_needed(accepted)
        effects = [h.effect for h in accepted]
        step('before/after on held-out data')
        pred1 = namer.pred.predict(effects, replay.joints)
        found = _found_effects(namer.pred, replay, split, cond, effects, accepted, pred0, pred1)
        # an effect that leaves most of its joints' excess over tick rounding is the nearest candidate
        # to physics the library does not hold, not that physics: not named (a slower motor on a
        # femur was taken for a torque limit, held-out 3.94 -> 2.22 ticks)
        weak = [i for i, f in enumerate(found) if _explained(f) < settings.min_final_explained]
        nearest = [(found[i], accepted[i]) for i in weak]
        if weak:
            keep = [i for i in range(len(found)) if i not in weak]
            found = [found[i] for i in keep]
            effects = [effects[i] for i in keep]
            pred1 = namer.pred.predict(effects, replay.joints)
        blind = _shown(blind, found)
    finally:
        namer.close()
    return effects, found, nearest, blind, pred1


def _swing_fits(log: list) -> dict:
    """{(effect, joint): value} of the effects the swings fitted on one joint: the namer's last round on it, in
    ``log`` (the loaded search leaves out a kind already named on the joint)."""
    return {(entry[2], entry[3][0]): entry[4] for entry in log if entry[0] == 'round' and len(entry[3]) == 1}


def _whole_walk_recording(rec: Recording, replay: Replay, phases: dict, mode_used: str):
    """(recording, gait phases) of the whole walk: one replay of the trunk on the ground cannot cross a lost
    span, so on a walk that lost one it is the recording up to the first, with that recording's phases."""
    if rec.lost and mode_used == 'walk':
        rec_ww = rec.before(rec.lost[0][0])
        return rec_ww, gait_phases(rec_ww, replay.legs)
    return rec, phases


def _term_chooser(rec_ww: Recording, robot: Robot, ground, ww_phases: dict, replay: Replay, notes: list, step):
    """``choose(named, terms)`` for :func:`_outside_the_list` on a walk: the dictionary's terms judged on the
    whole walk (:func:`~.structure.choose_terms`), its notes added to ``notes``."""
    def choose(named, terms):
        terms, more = structure.choose_terms(rec_ww, robot, named, terms, ground, ww_phases, replay.joints,
                                             progress=step)
        notes.extend(more)
        return terms
    return choose


def _joint_fits(replay: Replay, split, res0: dict, res1: dict) -> dict[Joint, JointFit]:
    jfit = {}
    for j in replay.joints:
        b, n = _rmse(res0, split.hold, [j])
        a, _ = _rmse(res1, split.hold, [j])
        jfit[j] = JointFit(b, a, n)
    return jfit


def _split_note(split, by_swing: bool) -> str:
    n_hold = sum(int(np.count_nonzero(m)) for m in split.hold.values())
    n_fit = sum(int(np.count_nonzero(m)) for m in split.fit.values())
    return (f'fitted on {n_fit} reads, judged on {n_hold} held-out reads ('
            + ('alternate swings of each leg)' if by_swing else f'alternating {split.block_s:g} s blocks)'))


def analyse(rec: Recording, robot: Robot | None = None, joints=None, windows=None, mode: str = 'auto',
            settings: FitSettings | None = None, block_s: float | None = None, progress: bool = False,
            workers: int = 2, ground=None, whole_walk: bool = True, search_budget_s: float = SEARCH_BUDGET_S
            ) -> Analysis:
    """Find what the nominal model of ``robot`` leaves out of ``rec`` (see the package docstring).

    ``joints``: restrict to these joints (:class:`~hexapod_model.joints.Joint`, or their names).
    ``windows``: list of (t_start, t_end) [s] to analyse
    (all legs), overriding the stand/walk choice. ``mode``: 'auto', 'stand' or 'walk'.
    ``block_s``: length of the alternating fit / held-out time blocks; default: 2 s on a stand or
    given windows, alternate swings of each leg on a walk (:func:`~.predict.make_split`).
    ``whole_walk``: on a walk, also replay the whole walk on the MuJoCo hexapod (:mod:`.whole_walk`) on
    ``ground`` (a :class:`~hexapod_sim.physics.terrain.Ground`; None: the recording's, else a flat floor).
    ``search_budget_s``: the seconds of walk its loaded-phase search may replay before it begins no further
    scope (:data:`~.loaded_search.SEARCH_BUDGET_S`).
    """
    t_start = time.perf_counter()
    if mode not in MODES:
        raise ValueError(f'mode must be one of {MODES}, got {mode!r}')
    robot = robot if robot is not None else load_robot()
    joints = None if joints is None else tuple(Joint.of(j) for j in joints)
    settings = settings or FitSettings()
    notes: list[str] = []
    bar, step = _progress_bar(progress)
    try:
        replay, pred0, res0, phases, mode_used, skip_start_s = replay_analysed(rec, robot, joints, windows, mode, notes,
                                                                               step)
        if mode_used == 'walk':          # a walk's larger held-out drop
            settings = replace(settings, min_drop_ticks=max(settings.min_drop_ticks, settings.walk_min_drop_ticks))
        by_swing = block_s is None and mode_used == 'walk'
        split = make_split(replay, block_s=block_s or 2.0, skip_start_s=skip_start_s, by_segment=by_swing)
        step('motion conditions')
        traj = {leg: replay.trajectory(robot, leg) for leg in replay.legs}
        cond = read_conditions(replay, robot, traj)
        mism = mismatch_windows(replay, res0, cond)
        step('naming and fitting effects')
        effects, found, nearest, blind, pred1 = _name_effects(replay, robot, split, settings, pred0, cond, step,
                                                              workers)
        res1 = replay.residuals(pred1)
        jfit = _joint_fits(replay, split, res0, res1)
        unexplained = _unexplained(replay, split, cond, res1, jfit, nearest)
        rec_ww, ww_phases = _whole_walk_recording(rec, replay, phases, mode_used)
        choose = _term_chooser(rec_ww, robot, ground, ww_phases, replay, notes, step) if (
            mode_used == 'walk' and whole_walk) else None
        terms, found, unexplained, res1, jfit = _outside_the_list(replay, robot, split, cond, effects, found,
                                                                  unexplained, res1, jfit, nearest, settings, step,
                                                                  choose)
        phase_fit, whole = {}, None
        if mode_used == 'walk':
            mism, phase_fit = _locate_phases(replay, phases, mism, res0, res1)
            if whole_walk:
                step('replaying the whole walk on the MuJoCo hexapod')
                named = [f.effect for f in found] + [t.effect for t in terms]
                whole, ww_notes, finds, wide, moved, swaps = whole_walk_check(
                    rec_ww, robot, named, ground, ww_phases, replay.joints, progress=step,
                    swing_fits=_swing_fits(settings.log), budget_s=search_budget_s)
                if moved:
                    found, unexplained, res1, jfit, phase_fit = _on_whole_legs(replay, robot, split, cond, phases, found,
                                                                               terms, moved, res0, jfit, nearest)
                if rec.lost:
                    notes.append(f'whole walk: replayed up to the first lost span, {rec_ww.duration_s:.1f} s')
                notes.extend(ww_notes)
                found, unexplained = widened(found, unexplained, wide, whole, replay.joints)
                found, terms = with_refits(found, terms, swaps)
                unexplained = whole_walk_agrees(unexplained, whole, rec_ww.duration_s)
                found, blind = add_loaded(found, blind, finds, replay.joints)
        notes.append(_split_note(split, by_swing))
        return Analysis(source=rec.source, mode=mode_used, robot=robot, replay=replay, split=split,
                        duration_s=rec.duration_s, residual_before=res0, residual_after=res1, conditions=cond,
                        mismatches=mism, effects=found, joints=jfit, notes=notes,
                        runtime_s=time.perf_counter() - t_start, log=list(settings.log),
                        glitches=tuple(rec.glitches), phase_fit=phase_fit, blind=blind,
                        min_drop_ticks=settings.min_drop_ticks, min_gain_ticks2=settings.min_gain_ticks2,
                        unexplained=unexplained, whole_walk=whole, terms=terms)
    finally:
        if bar is not None:
            bar.close()


__all__ = ['Analysis', 'FoundEffect', 'JointFit', 'analyse', 'MODES', 'Hypothesis']
