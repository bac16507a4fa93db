"""Which scope the namer fits and accepts for an effect: the smallest joints that carry it."""
from hexapod_model.joints import LEG_JOINTS, Joint
from hexapod_sim.discrepancy.effects import BY_NAME
from hexapod_sim.discrepancy.fit import WORSE_TICKS, FitSettings, Hypothesis, Namer


def _namer() -> Namer:
    namer = Namer.__new__(Namer)          # the scope rules read the settings only
    namer.s = FitSettings()
    return namer


def _hyp(effect: str, joints, gain: float) -> Hypothesis:
    return Hypothesis(BY_NAME[effect], tuple(joints), screen_gain=gain)


def test_an_effect_screened_best_on_a_leg_is_also_fitted_on_its_best_joint():
    leg = LEG_JOINTS[4]
    femur, tibia = Joint(4, 'femur'), Joint(4, 'tibia')
    every = tuple(j for legj in LEG_JOINTS.values() for j in legj)
    hyps = [_hyp('compliance_deadband', leg, 1340.0), _hyp('compliance_deadband', every, 1339.0),
            _hyp('compliance_deadband', (femur,), 1262.0), _hyp('compliance_deadband', (tibia,), 900.0)]
    picked = _namer()._pick_for_fit(hyps)
    assert [h.joints for h in picked] == [leg, (femur,)]


def test_an_effect_screened_best_on_one_joint_keeps_the_second_best_scope():
    femur = Joint(4, 'femur')
    hyps = [_hyp('backlash', (femur,), 50.0), _hyp('backlash', LEG_JOINTS[4], 40.0),
            _hyp('backlash', (Joint(4, 'tibia'),), 30.0)]
    assert [h.joints for h in _namer()._pick_for_fit(hyps)] == [(femur,), LEG_JOINTS[4]]


def _held_out(h: Hypothesis, rms: dict, n: int = 100) -> Hypothesis:
    h.hold_by_joint = {j: (b * b * n, a * a * n, n) for j, (b, a) in rms.items()}
    return h


def test_a_leg_wide_effect_that_makes_one_joint_clearly_worse_is_not_that_scope():
    coxa, femur, tibia = LEG_JOINTS[4]
    namer = _namer()
    worse = _held_out(_hyp('compliance_deadband', LEG_JOINTS[4], 0.0),
                      {coxa: (0.32, 0.83), femur: (2.08, 0.30), tibia: (2.21, 0.89)})
    assert namer._worsens_a_joint(worse)
    within = _held_out(_hyp('compliance_deadband', LEG_JOINTS[4], 0.0),
                       {coxa: (0.32, 0.32 + 0.5 * WORSE_TICKS), femur: (2.08, 0.30), tibia: (2.21, 0.89)})
    assert not namer._worsens_a_joint(within)
    one_joint = _held_out(_hyp('compliance_deadband', (coxa,), 0.0), {coxa: (0.32, 0.83)})
    assert not namer._worsens_a_joint(one_joint)      # judged by the acceptance test, not as a scope
    law = _held_out(_hyp('punch', tuple(LEG_JOINTS[4]), 0.0),
                    {coxa: (0.32, 0.83), femur: (2.08, 0.30), tibia: (2.21, 0.89)})
    assert not namer._worsens_a_joint(law)            # the servo law is on every servo
