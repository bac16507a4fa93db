"""Physics outside the candidate list, named by the dictionary's structure search (discrepancy.structure):
one-leg stand recordings of the MuJoCo plant (the calibration routine of leg 2)."""
import pytest

from hexapod_model.description import Effect, load_robot
from hexapod_model.joints import Joint
from hexapod_sim.discrepancy import analyse
from hexapod_sim.discrepancy.report import overlay_yaml, text_report, to_json

bench = pytest.importorskip('hexapod_locomotion.bench.dictionary_bench', reason='the locomotion package is not importable')
pytest.importorskip('hexapod_sim.physics.plant', reason='the MuJoCo sim package is not importable')


def _case(name):
    return next(c for c in bench.CASES if c.name == name)


def test_a_cable_spring_is_named_with_its_stiffness_and_rest_angle_and_the_overlay_reproduces_it(tmp_path):
    robot = load_robot()
    case = _case('spring-tibia')
    rec = bench.record(case, robot)
    a = analyse(rec, robot, workers=1)
    assert a.effects == [], text_report(a)
    assert [(t.effect.effect, t.effect.joints) for t in a.terms] == [('cable_spring', (Joint(2, 'tibia'),))], text_report(a)
    p = a.terms[0].effect.params
    assert p['stiffness_nm_per_rad'] == pytest.approx(0.3, abs=0.06)      # the bench's tolerances
    assert p['rest_angle_rad'] == pytest.approx(0.3, abs=0.1)
    assert a.terms[0].heldout_rmse_ticks_before / a.terms[0].heldout_rmse_ticks_after >= 1.5
    assert a.unexplained == []
    doc = to_json(a)
    assert doc['physics_terms'][0]['term'] == 'cable_spring' and 'unexplained' in doc and 'effects' in doc
    assert 'a spring pulling the joint toward a rest angle' in text_report(a)
    # the overlay, read back into the plant, reproduces the recording to tick rounding
    ov = tmp_path / 'fit.yaml'
    ov.write_text(overlay_yaml(a))
    fitted = load_robot(overlays=[ov])
    again = bench.record(bench.Case('fitted', None, None, None, None, {}), fitted)
    j = Joint(2, 'tibia')
    diff = (again.states[j].theta_rad - rec.states[j].theta_rad) / robot.servo.rad_per_tick
    assert len(diff) == len(rec.states[j].theta_rad)
    assert float((diff ** 2).mean()) ** 0.5 < 0.5


def test_a_spring_of_mujocos_own_in_the_mjcf_is_named_a_cable_spring():
    """A plant parameterised unlike the dictionary (MuJoCo's implicit joint spring, about the joint's zero)."""
    robot = load_robot()
    a = analyse(bench.record(_case('mjcf-spring-tibia'), robot), robot, workers=1)
    assert a.effects == [] and [t.effect.effect for t in a.terms] == ['cable_spring'], text_report(a)
    p = a.terms[0].effect.params
    assert p['stiffness_nm_per_rad'] == pytest.approx(0.3, abs=0.06)
    assert p['rest_angle_rad'] == pytest.approx(0.0, abs=0.1)


def test_load_proportional_friction_is_named_not_taken_for_a_list_candidate():
    robot = load_robot()
    a = analyse(bench.record(_case('load-femur'), robot), robot, workers=1)
    r = bench.score(_case('load-femur'), a)
    assert r['verdict'] == 'explained', (r, text_report(a))


def test_the_search_is_not_run_where_the_candidates_explain_everything():
    """A list effect in the plant is named from the list; the dictionary adds nothing beside it."""
    robot = load_robot()
    truth = Effect('coulomb_friction', ('leg2_tibia',), {'tau_c_nm': 0.08})
    case = bench.Case('coulomb', truth, None, None, None, {})
    a = analyse(bench.record(case, robot), robot, workers=1)
    assert [f.effect.effect for f in a.effects] == ['coulomb_friction'], text_report(a)
    assert a.terms == []
