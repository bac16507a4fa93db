"""The dictionary's torque terms (hexapod_model.dictionary) act alike in the swing-down model and in the
MuJoCo sim: one leg swinging free on a fixed base, femur and tibia following sine goals for 3 s."""
import math

import numpy as np
import pytest

from hexapod_model.description import ALL_JOINTS, DescriptionError, Effect, joint_name, load_robot, robot_from_dict
from hexapod_model.servo import goal_joint_tick
from hexapod_model.swing_model import LegModel

sim_mod = pytest.importorskip('hexapod_sim.physics.plant', reason='the MuJoCo sim package is not importable')

LEG = 2
N = 3000
T = np.arange(N) * 1e-3
TH2 = 0.5 * np.sin(2 * math.pi * T / 1.5)
TH3 = -0.4 + 0.6 * np.sin(2 * math.pi * T / 1.1)
FEMUR, TIBIA = joint_name(LEG, 'femur'), joint_name(LEG, 'tibia')


def _sim(robot):
    """MuJoCo: the leg's true angles per firmware period, and the rest of the robot's stall current [A]
    before the supply sag (from the applied torques, which are after it)."""
    sim = sim_mod.HexapodSim(robot, fixed_base=True)
    sim.reset(joint_angles={joint_name(LEG, 'coxa'): 0.0, FEMUR: TH2[0], TIBIA: TH3[0]})
    mine = [ALL_JOINTS.index(FEMUR), ALL_JOINTS.index(TIBIA)]
    others = np.ones(len(ALL_JOINTS), dtype=bool)
    others[mine] = False
    s = robot.servo
    inv_kt = 1.0 / (s.torque_constant_nm_per_a * s.gear_ratio)
    r_over_v = sum(e.params['resistance_ohm'] for e in robot.effects if e.effect == 'supply_sag') / s.supply_voltage_v
    q, i_ext = np.empty((N, 2)), np.empty(N)
    for k in range(N):
        q[k] = sim.true_joint_angles()[mine]
        sim.sync_write({FEMUR: TH2[k], TIBIA: TH3[k]})
        sim.step(1e-3)
        tau = np.abs(sim.applied_torque_nm()) * inv_kt
        i_ext[k] = tau[others].sum() / (1.0 - r_over_v * tau.sum())     # undo the sag: f = 1 - R S_after / V
    return q, i_ext


def _model(robot, i_ext=None):
    goals = np.stack([goal_joint_tick(TH2, robot.servo, robot.bus.by_joint(FEMUR)),
                      goal_joint_tick(TH3, robot.servo, robot.bus.by_joint(TIBIA))], axis=1)
    return LegModel(robot, LEG).rollout([TH2[0], TH3[0]], [0.0, 0.0], goals, i_ext=i_ext).q_rad[:N]


@pytest.fixture(scope='module')
def nominal():
    robot = load_robot()
    return robot, _sim(robot)[0], _model(robot)


@pytest.mark.parametrize('effect', [
    Effect('cable_spring', (TIBIA,), {'stiffness_nm_per_rad': 0.3, 'rest_angle_rad': 0.2}),
    Effect('periodic_friction', (TIBIA,), {'amplitude_nm': 0.15, 'period_rad': 0.3, 'phase_rad': 1.0}),
    Effect('load_friction', (FEMUR,), {'coefficient': 0.3}),
    Effect('supply_sag', ALL_JOINTS, {'resistance_ohm': 1.5}),
    Effect('weak_motor', (FEMUR,), {'torque_scale': 0.6, 'speed_scale': 0.6}),
], ids=lambda e: e.effect)
def test_a_term_changes_the_free_swing_alike_in_the_model_and_the_sim(nominal, effect):
    robot0, sim0, model0 = nominal
    robot = robot0.with_effects([effect])
    sim_q, i_ext = _sim(robot)
    model_q = _model(robot, i_ext)
    rpt = robot.servo.rad_per_tick
    change = np.sqrt(np.mean(((sim_q - sim0) / rpt) ** 2, axis=0))
    apart = np.sqrt(np.mean(((sim_q - model_q) / rpt) ** 2, axis=0))
    assert change.max() > 1.5, change              # the term moves the swing by ticks ...
    assert apart.max() < 0.1 + 0.05 * change.max(), (change, apart)   # ... and model and sim agree on it


def test_terms_are_validated_with_their_units():
    import yaml

    from hexapod_model.description import default_description_path
    base = yaml.safe_load(default_description_path().read_text())
    ok = dict(base, effects=[{'effect': 'cable_spring', 'joints': [TIBIA],
                              'params': {'stiffness_nm_per_rad': 0.3, 'rest_angle_rad': -0.4}}])
    assert robot_from_dict(ok).effects[0].params['rest_angle_rad'] == -0.4
    bad = dict(base, effects=[{'effect': 'weak_motor', 'joints': [FEMUR],
                               'params': {'torque_scale': 0.0, 'speed_scale': 1.0}}])
    with pytest.raises(DescriptionError, match='torque_scale'):
        robot_from_dict(bad)
