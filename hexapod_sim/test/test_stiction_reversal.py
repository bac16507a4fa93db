"""Static friction at a velocity reversal, in the MuJoCo sim and in the swing-down model alike.

A coxa coasting away from its goal against a drive torque between the Coulomb and the break-away
level decelerates, passes through rest, and from there static friction holds it: it must stay where
it turned. With a drive above the break-away level it must come back. The speed changes by ~0.05
rad/s per 1 ms step near the turn, so a rule that applies break-away friction only to a joint
*found* at rest at a step (the sim: slower than 1e-3 rad/s at a tick; the model: stopped by the
Coulomb impulse) holds it or not depending on where in a step the zero falls: before, over the
initial speeds below, the sim held at one of five and the model at one other. Both now count a
sign change within a step as passing through rest.
"""
import numpy as np
import pytest

from hexapod_model.description import ALL_JOINTS, Effect, joint_name, load_robot
from hexapod_model.servo import theta_to_tick
from hexapod_model.swing_model import CoxaModel
from hexapod_sim.physics.plant import HexapodSim

JOINT = 'leg1_coxa'
DRIVE_NM = 0.2          # saturated drive towards the goal (torque limit): 0.06 Coulomb < 0.2
SPEEDS = (0.5, 0.8, 1.0, 1.1, 1.3)   # initial speeds away from the goal [rad/s]
STEPS = 600             # 0.6 s at 1 ms


def _truth(tau_s_nm):
    return load_robot().with_effects([Effect('static_friction', (JOINT,), {'tau_s_nm': tau_s_nm}),
                                      Effect('torque_saturation', (JOINT,), {'tau_max_nm': DRIVE_NM})])


def _sim_run(robot, v0):
    sim = HexapodSim(robot, fixed_base=True)
    i = ALL_JOINTS.index(JOINT)
    q0 = sim.true_joint_angles()
    goal = float(q0[i]) - 0.5                      # far away: the drive stays at its limit
    sim.sync_write({JOINT: goal})
    sim.data.qvel[sim.model.joint(JOINT).dofadr[0]] = v0
    q = []
    for _ in range(STEPS):
        q.append(sim.true_joint_angles()[i])
        sim.step(0.001)
    pose = (float(q0[ALL_JOINTS.index(joint_name(1, 'femur'))]), float(q0[ALL_JOINTS.index(joint_name(1, 'tibia'))]))
    return np.array(q), float(q0[i]), goal, pose


def _model_run(robot, v0, q0, goal, pose):
    goal_tick = np.rint(theta_to_tick(goal, robot.servo))
    ro = CoxaModel(robot, 1, pose).rollout_coxa(q0, v0, np.full(STEPS, goal_tick))
    return ro.q_rad[:STEPS, 0]


@pytest.mark.parametrize('make', ['sim', 'model'])
@pytest.mark.parametrize('v0', SPEEDS)
def test_a_joint_held_at_its_reversal_stays_there(make, v0):
    robot = _truth(0.3)                             # break-away 0.3 > 0.2 drive
    q_sim, q0, goal, pose = _sim_run(robot, v0)
    q = q_sim if make == 'sim' else _model_run(robot, v0, q0, goal, pose)
    top = int(np.argmax(q))
    assert 10 < top < STEPS - 300                   # it turned early on
    tick = robot.servo.rad_per_tick
    assert np.ptp(q[top:]) < 0.05 * tick, f'{make}: slid {np.ptp(q[top:]) / tick:.2f} ticks back after the reversal'


def test_sim_and_model_turn_at_the_same_angle_and_break_away_alike():
    tick = load_robot().servo.rad_per_tick
    for tau_s in (0.3, 0.15):                       # held / broken away (0.15 < 0.2 drive)
        robot = _truth(tau_s)
        q_sim, q0, goal, pose = _sim_run(robot, 1.1)
        q_model = _model_run(robot, 1.1, q0, goal, pose)
        assert np.max(np.abs(q_sim - q_model)) < 0.5 * tick, f'tau_s {tau_s}'
        if tau_s < DRIVE_NM:
            assert q_sim[-1] < np.max(q_sim) - 20 * tick          # came back towards the goal
