"""Model extensions used by the discrepancy tool: gear backlash in the leg kernel, the 1-DOF coxa
model, and the stand calibration routine."""
import math

import numpy as np
import pytest

from hexapod_model.description import JOINT_ROLES, LEGS, Effect, load_robot
from hexapod_model.joints import Joint
from hexapod_model.servo import theta_to_tick
from hexapod_model.swing_model import CoxaModel, LegModel, coxa_axis_inertia_kgm2
from hexapod_sim.calibration.plan import PHASES, CalibrationError, calibration_plan, run_calibration


@pytest.fixture(scope='module')
def robot():
    return load_robot()


def _tibia_sweep(robot, n=4000):
    """Femur level, tibia goal ramped slowly from 0.4 rad before vertical to 0.4 rad past it."""
    vertical = -math.pi / 2 - robot.dh['femur'].theta_off_rad - robot.dh['tibia'].theta_off_rad
    th3 = np.linspace(vertical + 0.4, vertical - 0.4, n)
    goals = np.stack([np.full(n, float(robot.servo.center_tick)), np.rint(theta_to_tick(th3, robot.servo))], axis=1)
    return vertical, th3, goals


def test_zero_backlash_is_the_nominal_model(robot):
    _, th3, goals = _tibia_sweep(robot, 1500)
    a = LegModel(robot, 1).rollout([0.0, th3[0]], [0, 0], goals)
    b = LegModel(robot.with_effects([Effect('backlash', ('leg1_tibia',), {'width_rad': 0.0})]), 1).rollout(
        [0.0, th3[0]], [0, 0], goals)
    assert np.array_equal(a.q_rad, b.q_rad)
    assert np.all(b.gap_rad == 0.0)


def test_tibia_falls_across_the_play_when_its_gravity_load_reverses(robot):
    # Hand reasoning: with the gear play on the motor side of the potentiometer, the tibia rests on the
    # tooth that carries its weight (gap = -w/2 while gravity pulls towards lower theta_3 ... the sign
    # follows the gravity torque). Swept slowly through vertical, the gravity torque changes sign and
    # the link falls across the play: the gap flips to the other side, and for a moment the link runs
    # ahead of the nominal (no-play) model by a good part of the width w before the servo, which
    # senses the link, pulls it back; away from the crossing both agree.
    w = math.radians(1.5)
    vertical, th3, goals = _tibia_sweep(robot)
    nominal = LegModel(robot, 1).rollout([0.0, th3[0]], [0, 0], goals)
    model = LegModel(robot.with_effects([Effect('backlash', ('leg1_tibia',), {'width_rad': w})]), 1)
    ro = model.rollout([0.0, th3[0]], [0, 0], goals)
    gap = ro.gap_rad[:, 1]
    assert np.all(np.abs(gap) <= w / 2 + 1e-9)
    assert abs(gap[0]) == pytest.approx(w / 2)
    assert gap[-1] == pytest.approx(-gap[0], abs=0.05 * w)        # rests on the other tooth afterwards
    psi23 = ro.q_rad[:, 1] + robot.dh['femur'].theta_off_rad + robot.dh['tibia'].theta_off_rad
    k_cross = int(np.argmin(np.abs(psi23 + math.pi / 2)))
    flip = int(np.argmax(np.sign(gap) != np.sign(gap[0])))
    assert abs(flip - k_cross) < 300                                # within 0.3 s of passing vertical
    diff = np.abs(ro.q_rad[:, 1] - nominal.q_rad[:, 1])
    near = slice(max(flip - 50, 0), flip + 250)
    assert 0.35 * w < diff[near].max() < 1.3 * w
    far = np.r_[0:max(flip - 400, 1), min(flip + 800, len(diff) - 1):len(diff)]
    assert diff[far].max() < 0.35 * w


def test_coxa_axis_inertia_hand_derivation(robot):
    # femur = 0.22, tibia = 0.81 makes psi_2 = psi_2 + psi_3 = 0: the leg lies straight and horizontal.
    # COM radii from the coxa axis: 0.026; 0.052 + 0.046 = 0.098; 0.052 + 0.066 + 0.062 = 0.180 m.
    expected = (1.8026666666666667e-05 + 0.080 * 0.026 ** 2 + 2.904e-05 + 0.080 * 0.098 ** 2
                + 7.935e-05 + 0.050 * 0.180 ** 2)
    assert coxa_axis_inertia_kgm2(robot, 1, 0.22, 0.81) == pytest.approx(expected, rel=1e-9)
    # a 50 g payload at the tip (0.052 + 0.066 + 0.138 = 0.256 m from the axis) adds m r^2
    heavy = robot.with_effects([Effect('mass_error', ('leg1_tibia',), {'payload_kg': 0.05})])
    assert coxa_axis_inertia_kgm2(heavy, 1, 0.22, 0.81) - expected == pytest.approx(0.05 * 0.256 ** 2, rel=1e-9)
    # folding the leg up brings the mass to the axis
    assert coxa_axis_inertia_kgm2(robot, 1, 1.5, 1.5) < 0.5 * expected


def test_coxa_step_settles_on_its_goal_and_heavier_legs_respond_slower(robot):
    goal = np.full(600, float(robot.servo.center_tick + 40))
    light = CoxaModel(robot, 1, (0.22, 0.81)).rollout_coxa(0.0, 0.0, goal)
    heavy_robot = robot.with_effects([Effect('mass_error', ('leg1_coxa',), {'payload_kg': 0.3})])
    heavy = CoxaModel(heavy_robot, 1, (0.22, 0.81)).rollout_coxa(0.0, 0.0, goal)
    tick = theta_to_tick(light.q_rad[:, 0], robot.servo)
    # no gravity on the coxa: it settles within the Coulomb band (0.060 N m / (1.5/32 N m/tick) = 1.3 ticks)
    assert abs(tick[-1] - goal[0]) <= 1.3 + 0.5
    assert np.all(light.q_rad[:, 1] == 0.0)                         # the dummy joint never moves
    t_light = int(np.argmax(tick >= goal[0] - 20))
    t_heavy = int(np.argmax(theta_to_tick(heavy.q_rad[:, 0], robot.servo) >= goal[0] - 20))
    assert t_heavy > t_light


def test_calibration_plan_covers_the_conditions(robot):
    plan = calibration_plan(robot)
    assert 40.0 < plan.duration_s < 70.0
    assert [p.name for p in plan.phases] == list(PHASES)
    assert all(a.t_end_s == pytest.approx(b.t_start_s) for a, b in zip(plan.phases, plan.phases[1:]))
    for i, role in enumerate(JOINT_ROLES):
        lo, hi = robot.joint_limits_rad[role]
        assert lo <= plan.goals_rad[:, i].min() and plan.goals_rad[:, i].max() <= hi
    model = LegModel(robot, 1)

    def gravity_signs(phase, col):
        ph = next(p for p in plan.phases if p.name == phase)
        k = slice(int(ph.t_start_s / plan.dt_s), int(ph.t_end_s / plan.dt_s))
        return {np.sign(model.gravity_torque_nm(q[1:])[col]) for q in plan.goals_rad[k][::20]}
    assert gravity_signs('tibia', 1) >= {-1.0, 1.0}                 # tibia load reverses (backlash shows)
    assert gravity_signs('femur_reversal', 0) >= {-1.0, 1.0}        # femur load reverses
    coxa = next(p for p in plan.phases if p.name == 'coxa')
    assert plan.read_joints(coxa.t_start_s + 1.0) == [f'leg{leg}_coxa' for leg in LEGS]
    with pytest.raises(CalibrationError, match='unknown phase'):
        calibration_plan(robot, phases=('coxa', 'dance'))
    with pytest.raises(CalibrationError, match='legs'):
        calibration_plan(robot, legs=(7,))


class _ClockBus:
    """A ServoBus that returns the goal as the position: checks the routine's bus usage only."""

    t_com_s = 0.001

    def __init__(self):
        self.t = 0.0
        self.goals = {}
        self.log = []

    def now(self):
        return self.t

    def sync_write(self, goals_rad):
        self.goals.update(goals_rad)
        self.log.append(('w', self.t, len(goals_rad)))
        return self.t

    def read_position(self, joint):
        t = self.t
        self.t += self.t_com_s
        self.log.append(('r', t, joint))
        return self.goals[joint], t

    def wait_until(self, t):
        self.t = max(self.t, t)


def _goal_history(rec):
    """The written goal sets, in write order, rebuilt from the recording."""
    joints = sorted(rec.commands)
    n = len(rec.commands[joints[0]])
    return [{j: rec.commands[j].theta_rad[i] for j in joints} for i in range(n)]


def test_run_calibration_writes_changed_goals_and_reads_the_phase_joints(robot):
    plan = calibration_plan(robot, legs=(2, 5), phases=('tibia',))
    bus = _ClockBus()
    rec = run_calibration(bus, plan, progress=False)
    writes = [e for e in bus.log if e[0] == 'w']
    assert all(n == 6 for _, _, n in writes)                        # 2 legs x 3 joints in one sync write
    # a write only when some goal changes its integer tick: never two writes with the same ticks
    ticks = [np.rint(theta_to_tick(np.array(list(g.values())), robot.servo))
             for _, g in zip(writes, _goal_history(rec))]
    assert all(np.any(a != b) for a, b in zip(ticks, ticks[1:]))
    assert len(writes) < 0.5 * sum(1 for e in bus.log if e[0] == 'r')
    tibia = next(p for p in plan.phases if p.name == 'tibia')
    mid = [e for e in bus.log if e[0] == 'r' and tibia.t_start_s + 1 < e[1] < tibia.t_end_s - 1]
    assert {e[2] for e in mid} == {'leg2_tibia', 'leg5_tibia'}
    assert rec.commands[Joint(2, 'tibia')].t_s[0] == 0.0
    assert len(rec.states[Joint(5, 'tibia')]) > 0.45 * plan.duration_s / (2 * bus.t_com_s)
