"""Scoring of the discrepancy benchmark: an injected effect the tool did not find counts only where
the tool said the recording cannot show it AND the bench's check with the hidden truth agrees."""
from hexapod_locomotion.bench.discrepancy_bench import Case, score
from hexapod_model.description import Effect

LEG6 = ('leg6_coxa', 'leg6_femur', 'leg6_tibia')
CASE = Case('backlash@leg', (Effect('backlash', LEG6, {'width_rad': 0.02}),), walk=('pentapod', 'flat'))


def _result(found_joints, blind):
    return {'effects': [{'effect': 'backlash', 'joints': list(found_joints), 'params': {'width_rad': 0.021},
                         'heldout_rmse_ticks_before': 2.2, 'heldout_rmse_ticks_after': 0.35}],
            'cannot_show': {'backlash': list(blind)}}


def test_exact_joints_are_right_without_any_check():
    s = score(CASE, _result(LEG6, ()))
    assert s['right'] and s['right_strict'] and s['truth'][0]['located']


def test_missing_joints_count_only_if_said_and_confirmed():
    said = _result(('leg6_coxa',), ('leg6_femur', 'leg6_tibia', 'leg1_femur'))
    asked = []

    def confirm(effect, joints):
        asked.append(joints)
        return True
    s = score(CASE, said, truly_unshown=confirm)
    assert s['right'] and not s['right_strict']
    assert asked == [('leg6_femur', 'leg6_tibia')] and s['truth'][0]['unshown'] == ['leg6_femur', 'leg6_tibia']
    assert not score(CASE, said, truly_unshown=lambda e, j: False)['right']          # the truth disagrees
    assert not score(CASE, said)['right']                                             # no check, no credit
    assert not score(CASE, _result(('leg6_coxa',), ('leg6_femur',)), truly_unshown=confirm)['right']  # not said
    # found on a joint outside the truth: wrong, whatever it says it cannot show
    assert not score(CASE, _result(('leg6_coxa', 'leg5_coxa'), LEG6), truly_unshown=confirm)['right']


def test_a_servo_law_term_counts_for_its_robot_wide_joint_effect_twin_only():
    # a readout delay of every joint is a goal latency to the replay, viscous damping on every joint the
    # motor damping: found under the servo law's name they count for the truth, with the value converted
    from hexapod_model.description import ALL_JOINTS, load_robot
    b0 = load_robot().servo.reflected_damping_nms_per_rad
    every = list(ALL_JOINTS)
    case = Case('pair', (Effect('readout_delay', ALL_JOINTS, {'delay_s': 0.004}),
                         Effect('viscous_damping', ALL_JOINTS, {'b_nms_per_rad': 0.2 * b0})))
    found = {'effects': [{'effect': 'goal_latency', 'joints': every, 'params': {'delay_s': 0.0041},
                          'heldout_rmse_ticks_before': 1.4, 'heldout_rmse_ticks_after': 0.3},
                         {'effect': 'motor_damping', 'joints': every, 'params': {'ratio': 1.2},
                          'heldout_rmse_ticks_before': 1.1, 'heldout_rmse_ticks_after': 0.3}]}
    s = score(case, found)
    assert s['right_strict'] and all(r['param_ok'] for r in s['truth'])
    # a readout delay of one leg is no goal latency of every joint: that is a false effect
    leg = Case('leg', (Effect('readout_delay', LEG6, {'delay_s': 0.004}),))
    assert not score(leg, {'effects': [found['effects'][0]]})['right']
