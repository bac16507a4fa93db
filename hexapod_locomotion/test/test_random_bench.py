"""The random benchmark of the discrepancy tool: generator, visibility rule, scorer, command line, one real case."""
from __future__ import annotations

import numpy as np
import pytest

from hexapod_locomotion.bench import random_bench as rb
from hexapod_locomotion.bench import random_cases as rc
from hexapod_model.description import ALL_JOINTS, Effect


def _case(effects, classes, tolerance=None, walk=None, leg=2):
    return rc.RandomCase(0, tuple(effects), tuple(classes), leg=leg, walk=walk,
                         tolerance=tuple(tolerance or [{} for _ in effects]))


def _found(effect, joints, key, value, before=2.0, after=0.3, servo_law=False):
    return {'effect': effect, 'joints': list(joints), 'params': {key: value}, 'heldout_rmse_ticks_before': before,
            'heldout_rmse_ticks_after': after, 'servo_law': servo_law}


LEG2 = {j: {} for j in ('leg2_coxa', 'leg2_femur', 'leg2_tibia')}


# ----------------------------------------------------------------------------- generator
def test_the_draw_is_determined_by_the_seed_and_each_case_by_its_index():
    a, b = rc.make_cases(5, 30), rc.make_cases(5, 30)
    assert [c.label for c in a] == [c.label for c in b]
    assert [[e.params for e in c.effects] for c in a] == [[e.params for e in c.effects] for c in b]
    assert rc.draw_case(5, 17) == a[17]
    assert [c.label for c in rc.make_cases(6, 30)] != [c.label for c in a]


def test_a_hundred_cases_cover_every_category():
    cases = rc.make_cases(0, 100)
    cats: dict[str, set] = {}
    for c in cases:
        for group, values in rc.categories(c).items():
            cats.setdefault(group, set()).update(values)
    assert cats['setting'] == {'stand', 'walk'}
    assert {'tripod', 'tetrapod', 'pentapod'} <= cats['gait']
    assert {'flat', 'blocks'} <= cats['terrain']
    assert {'calibration', 'default'} <= cats['cycle']
    assert cats['class'] == set(rc.CLASSES)
    assert cats['size'] == {'single', 'pair'}
    kinds = {(e.effect, cls) for c in cases for e, cls in zip(c.effects, c.classes)}
    assert {k for k, cls in kinds if cls == 'out-of-list'} == set(rc.OUT_OF_LIST)
    assert {k for k, cls in kinds if cls == 'servo-law'} == set(rc.SERVO_LAW)
    scopes = {rc.scope_label(e.joints)[:3] for c in cases for e, cls in zip(c.effects, c.classes) if cls == 'in-list'}
    assert {'rob', 'leg'} <= scopes and any(s.startswith('leg') and '_' in s for c in cases for s in
                                            [rc.scope_label(e.joints) for e in c.effects])
    assert len({c.twin_key for c in cases}) < len(cases)      # twins shared by cases of the same routine or walk
    for c in cases:
        local = [e for e in c.effects if len(e.joints) < len(ALL_JOINTS)]
        assert sum(len(e.joints) == len(ALL_JOINTS) for e in c.effects) <= 1
        assert len({j for e in local for j in e.joints}) == sum(len(e.joints) for e in local)   # disjoint
        if not c.walk:
            assert all(j.leg == c.leg for e in local for j in e.joints)
            assert 'supply_sag' not in [e.effect for e in c.effects]


def test_out_of_list_magnitudes_are_drawn_around_the_dictionary_bench_cases():
    for c in rc.make_cases(0, 100):
        for e, cls, tol in zip(c.effects, c.classes, c.tolerance):
            if cls != 'out-of-list':
                continue
            assert tol, e
            for key, v in e.params.items():
                assert np.isfinite(v)
                if key not in rc.ANGLES:
                    assert v > 0


# ----------------------------------------------------------------------------- visibility
def test_the_visibility_rule_on_synthetic_residuals():
    rng = np.random.default_rng(1)
    n = 400
    labels = {'a': np.repeat([0, 1], n // 2), 'b': np.repeat([0, 1], n // 2), 'c': np.r_[np.zeros(390), np.ones(10)]}
    rounding = {j: rng.uniform(-0.5, 0.5, n) for j in labels}
    base = rc.phase_rms(rounding, labels, ('stance', 'swing'))
    shown = dict(rounding)
    shown['a'] = rounding['a'] + np.where(labels['a'] == 1, 1.0, 0.0)    # a tick off in one phase
    shown['b'] = rounding['b'] + np.where(labels['b'] == 1, 0.3, 0.0)    # less than the margin
    shown['c'] = rounding['c'] + np.where(labels['c'] == 1, 3.0, 0.0)    # in too few reads
    vis = rc.visible_joints(rc.phase_rms(shown, labels, ('stance', 'swing')), base)
    assert set(vis) == {'a'} and [p for p, _ in vis['a']] == ['swing']
    # the twin's own mismatch there raises the bar
    twin = rc.phase_rms({**rounding, 'a': rounding['a'] + np.where(labels['a'] == 1, 0.9, 0.0)}, labels,
                        ('stance', 'swing'))
    assert rc.visible_joints(rc.phase_rms(shown, labels, ('stance', 'swing')), twin) == {}
    # stand: against the other recording directly (baseline 0); unjudged reads (label -1) never count
    off = {'a': np.where(labels['a'] == 1, 1.0, 0.0)}
    assert set(rc.visible_joints(rc.phase_rms(off, {'a': labels['a']}, ('stance', 'swing')), None)) == {'a'}
    assert rc.visible_joints(rc.phase_rms(off, {'a': np.where(labels['a'] == 1, -1, 0)}, ('stance', 'swing')),
                             None) == {}


# ----------------------------------------------------------------------------- scorer
def test_right_effect_joint_and_parameter():
    case = _case([Effect('coulomb_friction', ('leg2_femur',), {'tau_c_nm': 0.08})], ['in-list'])
    res = {'joints': LEG2, 'effects': [_found('coulomb_friction', ['leg2_femur'], 'tau_c_nm', 0.085)]}
    s = rb.score(case, res, [['leg2_femur']])
    assert s['right'] and s['visible'] and rb.failure_kinds(s) == []


def test_wrong_parameter_is_wrong():
    case = _case([Effect('coulomb_friction', ('leg2_femur',), {'tau_c_nm': 0.08})], ['in-list'])
    res = {'joints': LEG2, 'effects': [_found('coulomb_friction', ['leg2_femur'], 'tau_c_nm', 0.12)]}
    s = rb.score(case, res, [['leg2_femur']])
    assert not s['right'] and s['rows'][0]['verdict'] == 'parameter off'


def test_wrong_or_missing_joints_and_nothing_found():
    case = _case([Effect('backlash', ('leg2_coxa', 'leg2_femur', 'leg2_tibia'), {'width_rad': 0.02})], ['in-list'])
    res = {'joints': LEG2, 'effects': [_found('backlash', ['leg2_coxa'], 'width_rad', 0.021)]}
    assert not rb.score(case, res, [['leg2_coxa', 'leg2_femur']])['right']          # femur shows it: missing
    assert rb.score(case, res, [['leg2_coxa']])['right']                            # only the coxa shows it
    # where the effect moves other joints too (the trunk on a walk), only its own joints are asked for
    assert rb.score(case, {'joints': {**LEG2, 'leg3_femur': {}}, 'effects': res['effects']},
                    [['leg2_coxa', 'leg3_femur']])['right']
    s = rb.score(case, {'joints': LEG2, 'effects': []}, [['leg2_coxa']])
    assert not s['right'] and s['rows'][0]['verdict'] == 'not found'
    # found on more joints than the truth's: wrong joints, not a second (false) effect
    one = _case([Effect('compliance_deadband', ('leg2_femur',), {'margin_ticks': 2.0})], ['in-list'])
    wide = {'joints': LEG2, 'effects': [_found('compliance_deadband', list(LEG2), 'margin_ticks', 2.01)]}
    s = rb.score(one, wide, [['leg2_femur']])
    assert not s['right'] and s['rows'][0]['verdict'] == 'wrong joints' and not s['false']


def test_a_false_effect_makes_a_case_wrong():
    case = _case([Effect('coulomb_friction', ('leg2_femur',), {'tau_c_nm': 0.08})], ['in-list'])
    res = {'joints': LEG2, 'effects': [_found('coulomb_friction', ['leg2_femur'], 'tau_c_nm', 0.08),
                                       _found('backlash', ['leg2_coxa'], 'width_rad', 0.02)]}
    s = rb.score(case, res, [['leg2_femur']])
    assert not s['right'] and [f['effect'] for f in s['false']] == ['backlash']
    # an invisible case: right without the false effect, wrong with it
    assert rb.score(case, {'joints': LEG2, 'effects': []}, [[]])['right']
    assert not rb.score(case, res, [[]])['right']


def test_a_list_candidate_for_out_of_list_physics_is_misnamed():
    truth = Effect('cable_spring', ('leg2_tibia',), {'stiffness_nm_per_rad': 0.3, 'rest_angle_rad': 0.3})
    tol = {'stiffness_nm_per_rad': (0.2, 'rel'), 'rest_angle_rad': (0.1, 'abs')}
    case = _case([truth], ['out-of-list'], [tol])
    res = {'joints': LEG2, 'effects': [_found('torque_saturation', ['leg2_tibia'], 'tau_max_nm', 1.1)]}
    s = rb.score(case, res, [['leg2_tibia']])
    assert not s['right'] and len(s['misnamed']) == 1 and not s['false']
    term = {'term': 'cable_spring', 'joints': ['leg2_tibia'], 'params': {'stiffness_nm_per_rad': 0.31,
                                                                         'rest_angle_rad': 0.35}}
    assert rb.score(case, {'joints': LEG2, 'physics_terms': [term]}, [['leg2_tibia']])['right']
    off = {**term, 'params': {'stiffness_nm_per_rad': 0.31, 'rest_angle_rad': 0.6}}
    s = rb.score(case, {'joints': LEG2, 'physics_terms': [off]}, [['leg2_tibia']])
    assert not s['right'] and s['rows'][0]['verdict'] == 'parameter off'


def test_out_of_list_physics_reported_unexplained_at_its_joint_is_right():
    case = _case([Effect('weak_motor', ('leg2_femur',), {'torque_scale': 0.6, 'speed_scale': 0.6})], ['out-of-list'],
                 [{'torque_scale': (0.17, 'rel')}])
    at = {'joints': LEG2, 'unexplained': [{'joints': ['leg2_femur'], 'condition': 'high_speed',
                                           'heldout_rmse_ticks': 3.9}]}
    s = rb.score(case, at, [['leg2_femur']])
    assert s['right'] and s['rows'][0]['how'] == 'unexplained'
    elsewhere = {'joints': LEG2, 'unexplained': [{'joints': ['leg2_coxa'], 'condition': 'moving',
                                                  'heldout_rmse_ticks': 1.0}]}
    s = rb.score(case, elsewhere, [['leg2_femur']])
    assert not s['right'] and s['false']


def test_a_robot_wide_delay_found_as_goal_latency_on_a_one_leg_stand():
    case = _case([Effect('readout_delay', ALL_JOINTS, {'delay_s': 0.004})], ['in-list'])
    res = {'joints': LEG2, 'effects': [_found('goal_latency', list(LEG2), 'delay_s', 0.0041, servo_law=True)]}
    assert rb.score(case, res, [list(LEG2)])['right']


def test_a_servo_law_term_found_as_its_joint_twin_on_some_joints_is_wrong_joints():
    case = _case([Effect('motor_damping', ALL_JOINTS, {'ratio': 1.28})], ['servo-law'])
    res = {'joints': LEG2, 'effects': [_found('viscous_damping', ['leg2_femur'], 'b_nms_per_rad', 0.056)]}
    s = rb.score(case, res, [list(LEG2)])
    assert not s['right'] and s['rows'][0]['verdict'] == 'wrong joints' and not s['false']
    assert abs(s['rows'][0]['fitted'] - 1.28) < 0.01


def test_a_clean_twin_is_right_only_when_nothing_is_claimed():
    assert rb.score_clean({'joints': LEG2, 'effects': [], 'physics_terms': [], 'unexplained': []})['right']
    assert not rb.score_clean({'effects': [_found('backlash', ['leg2_coxa'], 'width_rad', 0.02)]})['right']
    assert not rb.score_clean({'unexplained': [{'joints': ['leg2_coxa']}]})['right']


# ----------------------------------------------------------------------------- command line
@pytest.mark.parametrize('argv', [['--cases', '0'], ['--seed', '-1'], ['--only', '7', '--cases', '5'],
                                  ['--bogus'], ['--jobs', 'two'], ['--walk-seconds', '0'], ['--reuse']])
def test_bad_flags_are_one_line_and_exit_2(argv, capsys):
    with pytest.raises(SystemExit) as e:
        rb.main(argv)
    assert e.value.code == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and 'error' in err


# ----------------------------------------------------------------------------- one real case
def test_a_short_stand_case_through_the_real_tool(tmp_path):
    """The tibia part of the routine on leg 2 with a torque limit on the tibia: the twin is clean,
    the limit is visible on the tibia only, and the tool finds it."""
    case = rc.RandomCase(0, (Effect('torque_saturation', ('leg2_tibia',), {'tau_max_nm': 0.5}),), ('in-list',),
                         leg=2, tolerance=({},), phases=('settle', 'tibia'))
    twin = rb.run_twin((case, str(tmp_path / 'twin'), rb.WALK_S, False))
    assert twin['score']['right'], twin['score']
    r = rb.run_case((case, twin, str(tmp_path / 'case'), rb.WALK_S, False))
    assert r['visibility'] and set(r['visibility'][0]) == {'leg2_tibia'}, r
    assert r['right'], r['failures']
    assert r['rows'][0]['how'] == 'effect' and abs(r['rows'][0]['fitted'] - 0.5) < 0.05


def _analysed(index: int, tmp_path, **kw):
    """Case ``index`` of seed 0 recorded (its routine or walk with its effects) and analysed by the tool.
    -> (case, recording, analysis); ``kw`` goes to :func:`~hexapod_sim.discrepancy.analysis.analyse`."""
    from hexapod_model.description import load_robot
    from hexapod_sim.discrepancy.analysis import analyse
    case = rc.draw_case(0, index)
    _, rec = rb._record(case, 'case', case.effects, tmp_path, rb.WALK_S)
    return case, rec, analyse(rec, load_robot(), workers=1, **kw)


def test_a_goal_latency_fitted_beside_a_punch_is_not_named_where_the_punch_alone_does_better(tmp_path):
    """Case 51 of seed 0 (a pentapod calibration walk with 0.048 N m more punch and 0.19 N m s/rad of viscous
    damping on leg 3): the servo law's bundle is fitted while the leg's damping is still short, and a 2 ms
    goal latency came with 0.072 N m of punch. With the damping refitted, the punch alone leaves less on the
    held-out reads: it is named at its value, and no goal latency."""
    case, _, a = _analysed(51, tmp_path, whole_walk=False)
    punch, viscous = case.effects
    assert (punch.effect, viscous.effect) == ('punch', 'viscous_damping')
    found = {f.effect.effect: f.effect for f in a.effects}
    assert set(found) == {'punch', 'viscous_damping'}, found
    assert found['punch'].params['extra_punch_nm'] == pytest.approx(punch.params['extra_punch_nm'], rel=0.15)
    assert found['viscous_damping'].params['b_nms_per_rad'] == pytest.approx(viscous.params['b_nms_per_rad'],
                                                                              rel=0.10)
    assert set(found['viscous_damping'].joints) == set(viscous.joints)


def test_a_motor_damping_beside_a_weaker_motor_is_not_named_as_viscous_damping_of_single_joints(tmp_path):
    """Case 0 of seed 0 (a one-leg stand, 1.28x motor damping and a weaker tibia motor): the dictionary's
    weaker motor takes the tibia's share of the damping (0.54 of the no-load speed for 0.69), so beside it
    the motor damping does not pass and 0.057 N m s/rad of viscous damping was named on the coxa and the
    femur. Refitted beside the motor damping those twins stand for, the weaker motor lands on its values
    and the motor damping is named in their place."""
    case, _, a = _analysed(0, tmp_path)
    damping, weak = case.effects
    assert (damping.effect, weak.effect) == ('motor_damping', 'weak_motor')
    assert [f.effect.effect for f in a.effects] == ['motor_damping'], a.effects
    assert a.effects[0].effect.params['ratio'] == pytest.approx(damping.params['ratio'], rel=0.03)
    assert [t.effect.effect for t in a.terms] == ['weak_motor']
    for key, value in weak.params.items():
        assert a.terms[0].effect.params[key] == pytest.approx(value, rel=0.1), key


def test_a_torque_limit_fitted_a_little_low_is_refitted_not_joined_by_a_break_away_friction(tmp_path):
    """Case 65 of seed 0 (a tripod walk over the blocks, a 0.77 N m torque limit on leg 2's tibia): the
    swings fit the limit 0.5 % low, and at that value the whole walk leaves the tibia 1.1-1.3 ticks off in
    stance. The replay of the 12 s walk over the blocks carries the processor's floating-point rounding
    (the same pinned wheels take other vector code paths on another x86 processor) into what the
    loaded-phase search fits there: a break-away friction of 0.13 N m where this test was written, which
    the limit refitted on the whole walk explains as well (the limit is then refitted, closer to its
    value); 0.08 N m on an AMD EPYC (AVX2), below the least value the search names. Either way the limit
    alone is named, within 1 % of its value."""
    case, _, a = _analysed(65, tmp_path)
    (limit,) = case.effects
    assert limit.effect == 'torque_saturation'
    assert [f.effect.effect for f in a.effects] == ['torque_saturation'], a.effects
    assert not a.terms, a.terms
    fitted, truth = a.effects[0].effect.params['tau_max_nm'], limit.params['tau_max_nm']
    assert fitted == pytest.approx(truth, rel=0.01)
    if any('refitted on the whole walk' in n for n in a.notes):
        assert fitted == pytest.approx(truth, rel=0.005)


def test_a_break_away_friction_the_held_out_blocks_barely_show_is_judged_on_both_halves(tmp_path):
    """Case 76 of seed 0 (a tripod walk over the blocks, 0.32 N m of break-away friction on leg 2's
    tibia): the friction holds the tibia in a few stances, 0.95 ticks on the search's fit blocks and 0.39
    on the held-out ones, so the held-out blocks alone never pass it. Fitted on each half and judged on
    the other, it is named on the tibia within the bench's tolerance."""
    case, _, a = _analysed(76, tmp_path)
    (friction,) = case.effects
    assert friction.effect == 'static_friction'
    assert [(f.effect.effect, [str(j) for j in f.effect.joints]) for f in a.effects] == [
        ('static_friction', [str(j) for j in friction.joints])], a.effects
    assert a.effects[0].effect.params['tau_s_nm'] == pytest.approx(friction.params['tau_s_nm'], rel=0.25)


def test_an_angle_periodic_friction_is_not_named_as_the_coulomb_friction_of_its_mean(tmp_path):
    """Case 94 of seed 0 (a tripod walk over the blocks, angle-periodic friction of 0.12 N m every 0.34 rad
    on leg 3's tibia, beside a payload on leg 5): Coulomb friction of the periodic friction's mean passes
    on the swings (1.58 -> 0.53 ticks held out), above rounding but below the unexplained level. The
    dictionary's terms tried in its place find the periodic friction, which leaves less than half."""
    case, _, a = _analysed(94, tmp_path)
    (periodic,) = [e for e in case.effects if e.effect == 'periodic_friction']
    assert 'coulomb_friction' not in [f.effect.effect for f in a.effects], a.effects
    (term,) = [t for t in a.terms if t.effect.effect == 'periodic_friction']
    assert term.effect.joints == periodic.joints
    assert term.effect.params['period_rad'] == pytest.approx(periodic.params['period_rad'], rel=0.1)
    assert term.effect.params['amplitude_nm'] == pytest.approx(periodic.params['amplitude_nm'], rel=0.25)


def test_a_torque_limit_named_on_part_of_a_leg_is_tried_on_the_rest_beside_the_terms(tmp_path):
    """Case 55 of seed 0 (a one-leg stand, a 0.62 N m torque limit on every servo and a cable spring on the
    femur): the femur's 92 ticks of spring swamp the limit's fit on the femur and the tibia, so the limit
    was named on the coxa only and load friction stood for it on the tibia. Tried on the leg's other joints
    beside the terms (the spring fitted again with it), the limit takes the whole leg, the spring lands on
    its values and the load friction is dropped."""
    case, rec, a = _analysed(55, tmp_path)
    limit, spring = case.effects
    assert (limit.effect, spring.effect) == ('torque_saturation', 'cable_spring')
    assert [f.effect.effect for f in a.effects] == ['torque_saturation'], a.effects
    assert set(a.effects[0].effect.joints) == set(rec.joints), a.effects
    assert a.effects[0].effect.params['tau_max_nm'] == pytest.approx(limit.params['tau_max_nm'], rel=0.02)
    assert [(t.effect.effect, t.effect.joints) for t in a.terms] == [('cable_spring', spring.joints)], a.terms
    for key, value in spring.params.items():
        assert a.terms[0].effect.params[key] == pytest.approx(value, rel=0.05), key
    assert not a.unexplained, a.unexplained


def test_a_second_effect_on_a_joint_is_dropped_where_the_first_alone_refitted_does_as_well(tmp_path):
    """Case 29 of seed 0 (a tetrapod calibration walk over the blocks, an 8 ms readout delay on leg 5's femur
    beside 0.061 N m more punch): the delay was fitted at 2.8 ms before the punch was named, and beside the
    punch a Coulomb friction on the femur kept it at 3.5 ms. Without the friction, the delay fitted again
    from its whole range lands on its value and predicts the held-out reads better: the friction is not
    named."""
    case, _, a = _analysed(29, tmp_path, whole_walk=False)
    delay, punch = case.effects
    assert (delay.effect, punch.effect) == ('readout_delay', 'punch')
    found = {f.effect.effect: f.effect for f in a.effects}
    assert set(found) == {'readout_delay', 'punch'}, a.effects
    assert found['readout_delay'].joints == delay.joints
    assert found['readout_delay'].params['delay_s'] == pytest.approx(delay.params['delay_s'], rel=0.1)
    assert found['punch'].params['extra_punch_nm'] == pytest.approx(punch.params['extra_punch_nm'], rel=0.15)


def test_a_backlash_on_the_fourth_joint_by_loaded_phase_error_is_searched(tmp_path):
    """Case 83 of seed 0 (a tripod calibration walk over the blocks, 0.025 rad of backlash on leg 6's femur):
    on the blocks three other joints leave more error in the loaded phases than the femur does, and the
    backlash shows nowhere else. The loaded search tries the four joints with the largest loaded-phase
    error: the backlash is named on the femur within the bench's tolerance, and nothing else."""
    case, _, a = _analysed(83, tmp_path)
    (backlash,) = case.effects
    assert backlash.effect == 'backlash'
    assert [(f.effect.effect, f.effect.joints) for f in a.effects] == [('backlash', backlash.joints)], a.effects
    assert a.effects[0].effect.params['width_rad'] == pytest.approx(backlash.params['width_rad'], rel=0.25)
    assert not a.terms, a.terms


def test_a_small_coulomb_friction_beside_a_backlash_on_its_leg_is_found_on_the_whole_walk(tmp_path):
    """Case 2 of seed 0 (a tetrapod walk on flat ground, 0.063 N m of Coulomb friction on leg 2's tibia beside
    0.032 rad of backlash on its femur): with the backlash named, the friction takes the leg's held-out
    swings from 0.39 to 0.30 ticks only, below the walk's bar, and the tibia was reported unexplained. The
    whole walk shows it at the tibia's load reversals: fitted there on the joint, it is named within the
    bench's tolerance beside the backlash."""
    case, _, a = _analysed(2, tmp_path)
    friction, backlash = case.effects
    assert (friction.effect, backlash.effect) == ('coulomb_friction', 'backlash')
    found = {f.effect.effect: f.effect for f in a.effects}
    assert set(found) == {'coulomb_friction', 'backlash'}, a.effects
    assert found['coulomb_friction'].joints == friction.joints
    assert found['coulomb_friction'].params['tau_c_nm'] == pytest.approx(friction.params['tau_c_nm'], rel=0.25)
    assert found['backlash'].joints == backlash.joints
    assert not a.unexplained, a.unexplained
