"""Which scope the namer fits and accepts for an effect: the smallest joints that carry it."""
import pytest

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


def test_a_small_part_of_a_larger_effect_of_its_kind_is_that_effect_fitted_unevenly():
    """Beside 1.85x motor damping (0.17 N m s/rad of extra damping on every joint) a leg's 0.015 of viscous
    damping, and beside a leg's 0.166 its femur's 0.023, are the larger effect fitted unevenly; a leg's own
    damping of the larger effect's size, or on joints the larger one lacks, is physics of its own."""
    from hexapod_model.description import ALL_JOINTS, Effect, load_robot
    from hexapod_sim.discrepancy.fit import UNEVEN_SHARE, as_twin, uneven_parts
    robot = load_robot()
    motor = Effect('motor_damping', ALL_JOINTS, {'ratio': 1.85})
    assert as_twin(motor, robot) == pytest.approx(0.85 * robot.servo.reflected_damping_nms_per_rad)

    def viscous(joints, b):
        return Effect('viscous_damping', tuple(joints), {'b_nms_per_rad': b})

    small = viscous(LEG_JOINTS[1], 0.015)
    own = viscous(LEG_JOINTS[2], 0.5 * as_twin(motor, robot))
    assert uneven_parts([motor, small, own], robot) == [1]
    leg3, femur3 = viscous(LEG_JOINTS[3], 0.166), viscous((Joint(3, 'femur'),), 0.023)
    assert uneven_parts([leg3, femur3], robot) == [1]
    assert uneven_parts([leg3, viscous((Joint(3, 'femur'),), UNEVEN_SHARE * 0.166 * 1.2)], robot) == []
    assert uneven_parts([leg3, viscous((Joint(4, 'femur'),), 0.023)], robot) == []     # not on its joints
    latency = Effect('goal_latency', ALL_JOINTS, {'delay_s': 0.002})
    assert uneven_parts([latency, Effect('readout_delay', (Joint(5, 'tibia'),), {'delay_s': 0.0003})], robot) == [1]


def test_a_dictionary_term_must_remove_the_held_out_error_a_list_effect_must():
    """A coxa read 18 times in a walk's held-out swings, 0.77 -> 0.38 ticks: ratio and explained share pass,
    but the 8 tick^2 it removes confirm no term, as they confirm no list effect."""
    from hexapod_sim.discrepancy import structure

    class Objective:                  # the held-out squared error of the term's own joint at its value
        affected = [Joint(2, 'coxa')]
        term = type('T', (), {'params': ()})()

        def __init__(self, n, after):
            self.n, self.after = n, after

        def sse(self, x, which='fit', joints=None):
            return self.n * self.after ** 2

    def judged(n):
        obj = Objective(n, 0.38)
        before = n * 0.77 ** 2
        return structure._judge(obj, [], [Joint(2, 'coxa')], before, {Joint(2, 'coxa'): before}, n,
                                structure.SearchSettings())

    assert structure.SearchSettings().min_gain_ticks2 == FitSettings().min_gain_ticks2
    assert not judged(18)[2]
    assert judged(60)[2]


def test_a_term_that_replaced_a_list_effect_stays_when_small_terms_on_many_legs_are_dropped():
    """Joint terms on three legs or more are dropped as the trace of a robot-wide cause, except a term that
    replaced the list's effect on its joints: a femur's load friction (32.7 -> 0.26 ticks, where viscous
    damping left 0.71) beside a motor damping's small leftovers on four other legs."""
    from hexapod_model.description import Effect
    from hexapod_sim.discrepancy.structure import FoundTerm, on_few_legs

    def term(name, joint, params, before, after):
        return FoundTerm(Effect(name, (joint,), params), str(joint), name, before, after)

    load = term('load_friction', Joint(3, 'femur'), {'coefficient': 0.37}, 32.7, 0.26)
    small = [term('load_friction', Joint(leg, 'coxa'), {'coefficient': 0.04}, 0.76, 0.35) for leg in (4, 5, 6)]
    weak = term('weak_motor', Joint(2, 'tibia'), {'torque_scale': 0.98, 'speed_scale': 0.96}, 0.78, 0.30)
    assert on_few_legs([weak, load] + small, [load], 3) == [load]
    assert on_few_legs([weak, load] + small, [], 3) == []
    assert on_few_legs([weak, load, small[0]], [load], 3) == [weak, load, small[0]]


def test_twins_stand_for_the_servo_law_term_at_their_median_value():
    """Viscous damping named on a coxa and a femur at 0.057 N m s/rad is the twin of 1.28x motor damping on
    every joint (as_twin's inverse); readout delays of a goal latency; no twin, no term."""
    from hexapod_model.description import ALL_JOINTS, Effect, load_robot
    from hexapod_sim.discrepancy.fit import as_twin, law_of_twins
    robot = load_robot()
    b = 0.28 * robot.servo.reflected_damping_nms_per_rad
    twins = [Effect('viscous_damping', (Joint(4, role),), {'b_nms_per_rad': v})
             for role, v in (('coxa', b), ('femur', 1.02 * b), ('tibia', 0.9 * b))]
    law = law_of_twins(twins, robot, ALL_JOINTS)
    assert law.effect == 'motor_damping' and [str(j) for j in law.joints] == [str(j) for j in ALL_JOINTS]
    assert law.params['ratio'] == pytest.approx(1.28) and as_twin(law, robot) == pytest.approx(b)
    delays = [Effect('readout_delay', (Joint(3, r),), {'delay_s': 0.002}) for r in ('coxa', 'femur')]
    assert law_of_twins(delays, robot, ALL_JOINTS).params == {'delay_s': pytest.approx(0.002)}
    assert law_of_twins([Effect('backlash', (Joint(3, 'femur'),), {'play_rad': 0.02})], robot, ALL_JOINTS) is None
