"""The loaded-phase search's bookkeeping (:func:`search_loaded`): which effects it returns at which values
when a refit of an effect is the rival of a new one. The replays, fits and judgements are stood in for
(each is tested on recorded walks elsewhere); what is checked is what the search does with their answers."""
import math
from types import SimpleNamespace

import numpy as np

from hexapod_model.description import Effect, Joint
from hexapod_sim.discrepancy import loaded_search

J1, J2, J3 = Joint(leg=1, role='tibia'), Joint(leg=2, role='tibia'), Joint(leg=3, role='femur')


def _friction(joint, value):
    return Effect('static_friction', (joint,), {'tau_s_nm': value})


def _walk(excess: dict):
    """A walk in step to 20 s whose stance leaves ``excess`` ({joint: RMS ticks}) on its joints."""
    t = np.arange(0.0, 20.0, 0.01)
    rec = SimpleNamespace(states={j: SimpleNamespace(t_s=t) for j in excess})
    replays = SimpleNamespace(rec=rec, robot=SimpleNamespace(servo=SimpleNamespace(rad_per_tick=0.005)),
                              replayed_s=0.0)
    ww = SimpleNamespace(in_step_until_s=20.0,
                         phases={j: {'stance': SimpleNamespace(n_reads=500, rmse_ticks_fitted=v)} for j, v in excess.items()})
    return replays, ww


def _search(monkeypatch, effects, new_on_scope: dict, rival_on_scope: dict):
    """``search_loaded`` where the best candidate on a scope is ``new_on_scope[scope]`` (held out 1.0 -> 0.3
    ticks) and the rival there, when given, is the effect list ``rival_on_scope[scope]`` (held out 0.3)."""
    monkeypatch.setattr(loaded_search, '_base_pred', lambda replays, base, joints, until: {})
    monkeypatch.setattr(loaded_search, '_best_on_scope',
                        lambda replays, base, pred, scope, *a: (1.0, 0.3, new_on_scope[tuple(scope)], 0.3))

    def rival(replays, base, scope, *a):
        if tuple(scope) not in rival_on_scope:
            return None
        refit = rival_on_scope[tuple(scope)](base)
        swapped = [(o, n) for o, n in zip(base, refit) if n is not o]
        return 0.3, refit, swapped[0]

    monkeypatch.setattr(loaded_search, '_rival', rival)
    replays, ww = _walk({J1: 1.2, J2: 1.0})
    return loaded_search.search_loaded(replays, list(effects), ww)


def test_a_find_refitted_as_a_later_scopes_rival_is_returned_at_its_refitted_value(monkeypatch):
    # leg 1's friction is found first; on leg 2's tibia its refit (0.20 -> 0.21) explains as much as a new
    # friction there: nothing new, and leg 1's find carries the value the rest of the search used
    first = _friction(J1, 0.20)
    found, refitted, _ = _search(monkeypatch, [], {(J1,): first, (J2,): _friction(J2, 0.25)},
                                 {(J2,): lambda base: [_friction(J1, 0.21) if e is first else e for e in base]})
    assert [f.effect.params['tau_s_nm'] for f in found] == [0.21]
    assert found[0].effect.joints == (J1,)
    assert refitted == []          # a find is no named effect: no "refitted" note


def test_a_named_effect_refitted_as_the_rival_is_reported_as_refitted(monkeypatch):
    named = Effect('torque_saturation', (J3,), {'tau_max_nm': 0.77})
    refit = Effect('torque_saturation', (J3,), {'tau_max_nm': 0.776})
    found, refitted, _ = _search(monkeypatch, [named], {(J1,): _friction(J1, 0.20), (J2,): _friction(J2, 0.25)},
                                 {(J1,): lambda base: [refit if e is named else e for e in base]})
    assert [f.effect.joints for f in found] == [(J2,)]
    assert refitted == [(named, refit)]


def test_no_scope_is_begun_once_the_search_has_replayed_its_budget(monkeypatch):
    # each scope's search replays 100 s of walk and names nothing; the joints come largest error first
    searched = []

    def best_on_scope(replays, base, pred, scope, *a):
        searched.append(tuple(scope))
        replays.replayed_s += 100.0
        return None

    monkeypatch.setattr(loaded_search, '_base_pred', lambda replays, base, joints, until: {})
    monkeypatch.setattr(loaded_search, '_best_on_scope', best_on_scope)
    replays, ww = _walk({J1: 1.2, J2: 0.8, J3: 1.0})
    found, refitted, left = loaded_search.search_loaded(replays, [], ww, budget_s=150.0)
    assert searched == [(J1,), (J3,)] and found == [] and refitted == []
    assert left == [((J2,), 0.8)]                  # 200 s replayed when leg 2's tibia came: not begun
    searched.clear()
    replays, ww = _walk({J1: 1.2, J2: 0.8, J3: 1.0})
    assert loaded_search.search_loaded(replays, [], ww, budget_s=math.inf)[2] == []
    assert searched == [(J1,), (J3,), (J2,)]


def _searched_kinds(monkeypatch, base, scope):
    """The candidate kinds :func:`_best_on_scope` fits on ``scope`` beside ``base`` (its fits stood in for)."""
    kinds = []

    def search_one(replays, base_, cand, scope_, until_s, fit, progress, **kw):
        kinds.append(cand.effect)
        return 0.1, 1.0, SimpleNamespace(pred={})

    monkeypatch.setattr(loaded_search, 'search_one', search_one)
    monkeypatch.setattr(loaded_search, 'masked_rms', lambda replays, pred, joints, masks: 1.0)
    best = loaded_search._best_on_scope(None, base, {}, scope, 20.0, {}, {}, lambda msg: None, {})
    return kinds, best


def test_a_kind_named_on_every_joint_of_the_scope_is_not_tried_again(monkeypatch):
    kinds, best = _searched_kinds(monkeypatch, [_friction(J1, 0.2)], (J1,))
    assert kinds == ['backlash', 'compliance_deadband'] and best is not None
    kinds, _ = _searched_kinds(monkeypatch, [_friction(J1, 0.2)], (J1, J2))      # not on J2: tried
    assert kinds == list(loaded_search.LOADED_CANDIDATES)
    named = [Effect(k, (J1,), {'x': 1.0}) for k in loaded_search.LOADED_CANDIDATES]
    kinds, best = _searched_kinds(monkeypatch, named, (J1,))
    assert kinds == [] and best is None


def _scope_searches(monkeypatch, before: tuple[float, float], cand_fit: float, cand_hold: float):
    """The searches :func:`_best_on_scope` runs on one joint whose fit and held-out blocks the nominal replay
    leaves at ``before`` (fit, held out) ticks, where every candidate's fit leaves them at ``cand_fit`` and
    ``cand_hold``: [(candidate, 'fit' or 'hold')], and its answer."""
    fit, hold = {J1: np.ones(50, dtype=bool)}, {J1: np.ones(50, dtype=bool)}
    base_pred, cand_pred = {}, {}
    rms = {(id(base_pred), id(fit)): before[0], (id(base_pred), id(hold)): before[1],
           (id(cand_pred), id(fit)): cand_fit, (id(cand_pred), id(hold)): cand_hold}
    runs = []

    def search_one(replays, base_, cand, scope_, until_s, masks, progress, **kw):
        runs.append((cand.effect, 'fit' if masks is fit else 'hold'))
        return 0.1, (cand_fit if masks is fit else cand_hold), SimpleNamespace(pred=cand_pred)

    monkeypatch.setattr(loaded_search, 'search_one', search_one)
    monkeypatch.setattr(loaded_search, 'masked_rms', lambda replays, pred, joints, masks: rms[id(pred), id(masks)])
    best = loaded_search._best_on_scope(None, [], base_pred, (J1,), 20.0, fit, hold, lambda msg: None, {})
    return runs, best


def test_a_scope_both_halves_of_which_are_near_tick_rounding_is_not_searched(monkeypatch):
    floor = loaded_search.FLOOR_RATIO * loaded_search.ROUNDING_RMS
    runs, best = _scope_searches(monkeypatch, (0.99 * floor, 0.9 * floor), 0.29, 0.29)
    assert runs == [] and best is None
    runs, best = _scope_searches(monkeypatch, (0.9 * floor, 1.01 * floor), 0.29, 0.29)      # one half above it
    assert len(runs) == len(loaded_search.LOADED_CANDIDATES) and best is not None


def test_the_held_out_blocks_are_fitted_only_where_both_halves_could_then_pass(monkeypatch):
    # the fit blocks explained 1.7x, the held-out ones barely: with the fit blocks at 0.7 ticks, both
    # halves together go from 1.06 to 0.78 ticks, under the 1.5x an effect needs
    runs, best = _scope_searches(monkeypatch, (1.2, 0.9), 0.7, 0.85)
    assert all(kind == 'fit' for _, kind in runs) and not loaded_search._passes(best[0], best[1])
    # with the fit blocks at 0.4 ticks they could (1.06 -> 0.51): the held-out blocks are fitted too
    runs, best = _scope_searches(monkeypatch, (1.2, 0.9), 0.4, 0.6)
    assert runs[-1][1] == 'hold' and sum(kind == 'hold' for _, kind in runs) == 1
