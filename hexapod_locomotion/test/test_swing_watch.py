"""A swinging leg's motion in the air and the obstacles it meets (core.swing_watch), and the controller's
reflex: a leg held by a block's side is lifted higher instead of pushing the trunk up."""
import numpy as np
import pytest

from hexapod_locomotion.core.locomotion_params import LocomotionParams
from hexapod_locomotion.core.swing_watch import in_air_rollouts, obstructed
from hexapod_locomotion.trials.trial_config import TrialConfig
from hexapod_locomotion.trials.trial_runner import run_trial
from hexapod_model.description import load_robot
from hexapod_model.swing_model import LegModel


@pytest.fixture(scope='module')
def robot():
    return load_robot()


def _swing(robot, legs=(1, 4)):
    """Rollouts of legs lifting their femur by 0.3 rad over 0.1 s, goals written every 10 ms."""
    models = {leg: LegModel(robot, leg) for leg in legs}
    start = np.array([[0.4, -0.9]] * len(legs))
    log = [(0.01 * i, start + np.array([0.3 * min(i, 10) / 10, 0.0])) for i in range(21)]
    return models, log, in_air_rollouts(models, legs, log, robot.servo, 0.2)


def test_a_leg_that_follows_its_motion_in_the_air_meets_nothing(robot):
    legs = (1, 4)
    models, log, ro = _swing(robot, legs)
    assert in_air_rollouts(models, legs, log[:1], robot.servo, 0.0) is None
    assert len(ro) == 2 and ro[0].q_rad[-1, 0] == pytest.approx(0.7, abs=0.02)     # it got there
    at = 0.05
    i = int(round(at / ro[0].dt_s))
    on_track = {leg: [(float(ro[s].q_rad[i, 0]), at), (float(ro[s].q_rad[i, 1]), at)] for s, leg in enumerate(legs)}
    limit = 25 * robot.servo.rad_per_tick
    assert obstructed(ro, legs, 0.0, on_track, limit) == {}
    # the goal is not the measure: mid-swing the femur lags its goal by more than the limit, and meets nothing
    assert log[5][1][0, 0] - ro[0].q_rad[i, 0] > 0.5 * limit


def test_a_leg_held_back_has_met_an_obstacle(robot):
    legs = (1, 4)
    _, _, ro = _swing(robot, legs)
    limit = 25 * robot.servo.rad_per_tick
    i = int(round(0.1 / ro[0].dt_s))
    held = float(ro[1].q_rad[i, 1]) - 1.5 * limit
    reads = {1: [(float(ro[0].q_rad[i, 0]), 0.1), None],
             4: [(float(ro[1].q_rad[i, 0]), 0.1), (held, 0.1)]}
    hit = obstructed(ro, legs, 0.0, reads, limit)
    assert list(hit) == [4] and hit[4] == pytest.approx(1.5 * limit, rel=1e-6)
    # a read from before the swing began says nothing about it
    reads[4][1] = (held, -0.01)
    assert obstructed(ro, legs, 0.0, reads, limit) == {}


def test_the_node_lifts_an_obstructed_leg_and_the_trials_keep_the_papers_swing():
    assert LocomotionParams().obstacle_lift_m > 0
    assert TrialConfig().obstacle_lift_m == 0.0


def _blocks_walk(lift):
    return run_trial(TrialConfig(gait='tripod', terrain='blocks', seed=9, duration_s=14.0, heading_correction=True,
                                 obstacle_lift_m=lift))


def test_a_leg_lifted_over_a_block_does_not_lift_the_trunk_off_its_stance_feet():
    """Tripod over the blocks (seed 9): in its swings leg 2 meets a block's side. Pushed on, it lifted the
    trunk off two of its three stance feet, which then followed their commands in the air: the legs-only
    odometry built up its yaw error while a foot it took as standing was off the ground (sim truth).
    Lifted higher, the foot clears the block and the stance feet stay down."""
    pushed, lifted = _blocks_walk(0.0), _blocks_walk(0.03)
    assert not any('met an obstacle' in w for w in pushed.warnings)
    assert any('met an obstacle' in w for w in lifted.warnings)
    assert abs(pushed.odometry['legs']['yaw_error_off_ground_deg']) > 15
    assert abs(lifted.odometry['legs']['yaw_error_off_ground_deg']) < 5
    assert abs(lifted.odometry['legs']['yaw_error_deg']) < 0.3 * abs(pushed.odometry['legs']['yaw_error_deg'])
