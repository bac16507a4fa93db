"""A servo-law term beside a joint effect: neither explains enough of the joint they share alone, so the
namer fits them as a pair (one-leg stand recordings of the MuJoCo plant, the calibration routine of leg 2)."""
import pytest

from hexapod_model.description import ALL_JOINTS, Effect, load_robot
from hexapod_model.joints import Joint
from hexapod_sim.discrepancy import analyse
from hexapod_sim.discrepancy.report import text_report

bench = pytest.importorskip('hexapod_locomotion.bench.dictionary_bench', reason='the locomotion package is not importable')
pytest.importorskip('hexapod_sim.physics.plant', reason='the MuJoCo sim package is not importable')


def _record(robot, *effects):
    return bench.record(bench.Case('pair', None, None, None, None, {}), robot.with_effects(list(effects)))


def test_more_punch_beside_a_tibia_dead_band_names_both_with_their_values():
    robot = load_robot()
    tibia = Joint(2, 'tibia')
    rec = _record(robot, Effect('punch', ALL_JOINTS, {'extra_punch_nm': 0.15}),
                  Effect('compliance_deadband', (tibia,), {'margin_ticks': 3.0}))
    a = analyse(rec, robot, workers=1)
    named = {f.effect.effect: f.effect for f in a.effects}
    assert sorted(named) == ['compliance_deadband', 'punch'] and a.terms == [], text_report(a)
    assert named['compliance_deadband'].joints == (tibia,)
    assert named['compliance_deadband'].params['margin_ticks'] == pytest.approx(3.0, rel=0.25)   # the bench's tolerance
    assert named['punch'].params['extra_punch_nm'] == pytest.approx(0.15, rel=0.25)
    assert a.unexplained == [], text_report(a)
