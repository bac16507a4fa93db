"""The discrepancy tool on a recording of the MuJoCo sim (the concealed generator: the tool only
gets the recording, never the sim's model). One leg on the stand, tibia phase of the calibration
routine (~15 s simulated)."""
import math

import pytest

from hexapod_sim.calibration import calibration_plan, run_calibration
from hexapod_model.description import JOINT_ROLES, Effect, joint_name, load_robot
from hexapod_sim.discrepancy import analyse
from hexapod_sim.discrepancy.report import text_report

sim_mod = pytest.importorskip('hexapod_sim.plant', reason='the MuJoCo sim package is not importable')


def _record(robot_truth, plan):
    sim = sim_mod.HexapodSim(robot_truth, fixed_base=True)
    sim.reset(joint_angles={joint_name(leg, r): float(plan.goals_rad[0, i])
                            for leg in plan.legs for i, r in enumerate(JOINT_ROLES)})
    return run_calibration(sim, plan, progress=False)


def test_backlash_in_the_mujoco_sim_is_named_located_and_fitted():
    robot = load_robot()
    width = math.radians(1.6)
    truth = Effect('backlash', ('leg4_tibia',), {'width_rad': width})
    rec = _record(robot.with_effects([truth]), calibration_plan(robot, legs=(4,), phases=('tibia',)))
    a = analyse(rec, robot, workers=1)
    assert [(f.effect.effect, f.effect.joints) for f in a.effects] == [('backlash', ('leg4_tibia',))], text_report(a)
    found = a.effects[0]
    assert found.effect.params['width_rad'] == pytest.approx(width, rel=0.25)
    assert found.heldout_rmse_ticks_before / found.heldout_rmse_ticks_after >= 1.5
    assert found.condition == 'load_reversal'


def test_break_away_friction_on_a_coxa_is_found_between_two_firmware_torque_levels():
    """A coxa carries no gravity load, so its break-away friction shows only against the firmware's
    torque, which takes one value per integer error: 0.153 N m lies between the 3- and 4-tick
    levels (0.141, 0.188 N m), and every value between them gives the same motion. The screen
    probes one value per such band (probes at 0.1, 0.2 and 0.4 N m found nothing here)."""
    robot = load_robot()
    truth = Effect('static_friction', ('leg2_coxa',), {'tau_s_nm': 0.153})
    rec = _record(robot.with_effects([truth]), calibration_plan(robot, legs=(2,), phases=('coxa',)))
    a = analyse(rec, robot, workers=1)
    assert [(f.effect.effect, f.effect.joints) for f in a.effects] == [('static_friction', ('leg2_coxa',))], text_report(a)
    found = a.effects[0]
    g = robot.servo.gain_nm_per_tick
    assert 3 * g < found.effect.params['tau_s_nm'] < 4 * g
    assert found.heldout_rmse_ticks_before / found.heldout_rmse_ticks_after >= 1.5
