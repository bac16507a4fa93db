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
