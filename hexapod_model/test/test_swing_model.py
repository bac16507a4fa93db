"""The swing-down model (Eq. 11-17): physics checks and the paper's Fig. 8/9 behaviour."""
import math

import numpy as np
import pytest

from hexapod_model.description import Effect, load_robot
from hexapod_model.servo import theta_to_tick
from hexapod_model.swing_model import (
    CoxaModel,
    LegModel,
    SwingDownError,
    goal_fraction,
    goals_per_period,
    interpolated_goals,
    predict_swing_down,
    rollout_batch,
    steps_to_fin,
)

RAISED = [0.45, 0.1]     # femur, tibia at the end of swing-forward [rad]
BELOW = [-0.15, -0.05]   # theta_fin: below the expected ground


@pytest.fixture(scope='module')
def robot():
    return load_robot()


def test_energy_is_conserved_without_damping_friction_control(robot):
    model = LegModel(robot, 1, substeps=20, control=False, friction=False, damping=False)
    q0 = np.array([0.6, 0.4])
    ro = model.rollout(q0, [0.0, 0.0], np.zeros((2000, 2)))
    e = np.array([model.energy_j(q, qd) for q, qd in zip(ro.q_rad[::50], ro.qd_rad_s[::50])])
    ke_max = max(0.5 * qd @ model.mass_matrix(q) @ qd for q, qd in zip(ro.q_rad, ro.qd_rad_s))
    assert ke_max > 0.01                                    # the leg really fell and swung
    assert np.max(np.abs(e - e[0])) < 2e-3 * ke_max
    # with damping switched back on, energy only decreases
    damped = LegModel(robot, 1, substeps=20, control=False, friction=False)
    ro = damped.rollout(q0, [0.0, 0.0], np.zeros((2000, 2)))
    e = np.array([damped.energy_j(q, qd) for q, qd in zip(ro.q_rad[::10], ro.qd_rad_s[::10])])
    assert np.all(np.diff(e) < 1e-9)


@pytest.mark.parametrize('q', [[0.0, 0.0], [0.3, 0.2], [-0.2, 0.5]])
def test_steady_state_femur_error_is_gravity_over_gain(robot, q):
    # Hand derivation: at rest the servo must supply G(q); the firmware torque is the punch
    # (1.5 N m x 32/1023) plus (1.5 N m / 32) per tick of error, so the error is (G - punch) / (1.5/32)
    # ticks. The firmware sees integer ticks, so the leg settles on the tick boundary nearest that
    # value: within half a tick.
    f, t = robot.links['femur'], robot.links['tibia']
    psi2 = q[0] - 0.22
    psi23 = psi2 + q[1] - 0.81
    g_femur = 9.81 * ((f.mass_kg * 0.046 + t.mass_kg * 0.066) * math.cos(psi2) + t.mass_kg * 0.062 * math.cos(psi23))
    expected = (g_femur - 1.5 * 32 / 1023) / (1.5 / 32)
    model = LegModel(robot, 1, friction=False)
    goal = np.rint(theta_to_tick(np.array(q), robot.servo))
    ro = model.rollout(q, [0, 0], np.tile(goal, (4000, 1)))
    err = goal[0] - theta_to_tick(ro.q_rad[2000:, 0], robot.servo)
    assert np.std(err) < 0.05                                # settled
    assert abs(err.mean() - expected) <= 0.5 + 1e-6
    assert expected > 0.5                                   # a real, visible gravity error


def test_one_substep_matches_fine_integration(robot):
    init, fin = np.array([RAISED] * 3), np.array([BELOW] * 3)
    for t_des in (0.5, 1.0, 2.0):
        fine = predict_swing_down(robot, [1, 6, 3], init, fin, t_des, 0.001,
                                  models={leg: LegModel(robot, leg, substeps=50) for leg in (1, 6, 3)})
        coarse = predict_swing_down(robot, [1, 6, 3], init, fin, t_des, 0.001)
        assert np.max(np.abs(fine.theta_est_tick - coarse.theta_est_tick)) < 0.1


def test_interpolation_eq15():
    g = interpolated_goals(100.0, 40.0, t_des_s=0.03, t_con_s=0.003, n_steps=12)
    assert g[0] == pytest.approx(94.0) and g[9] == pytest.approx(40.0) and g[11] == pytest.approx(40.0)
    assert np.diff(g[:10]) == pytest.approx(np.full(9, -6.0))


def test_approach_profile_slows_the_goal_after_approach_from():
    # rate 1 is Eq. 15 to the bit; rate 0.5 from 0.6 on: the goal of step k is 0.6 + 0.5 ((k + 1) / 10 - 0.6)
    k = np.arange(20)
    assert np.array_equal(goal_fraction(k, 10.0, 0.6, 1.0), np.minimum((k + 1.0) / 10.0, 1.0))
    frac = goal_fraction(k, 10.0, 0.6, 0.5)
    assert frac[:6] == pytest.approx((k[:6] + 1) / 10.0)
    assert frac[6:14] == pytest.approx(0.6 + 0.5 * ((k[6:14] + 1) / 10.0 - 0.6))
    assert frac[13] == pytest.approx(1.0) and frac[12] < 1.0 and frac[19] == 1.0
    assert steps_to_fin(10.0, 0.6, 0.5) == 14 and steps_to_fin(10.0, [0.6, 0.9], 0.5) == 14
    assert steps_to_fin(10.0, 0.3, 1.0) == 10
    g = interpolated_goals([100.0, 200.0], [40.0, 80.0], 0.03, 0.003, 14, approach_from=[0.6, 1.0], approach_rate=0.5)
    assert g[:, 0] == pytest.approx(100.0 - 60.0 * frac[:14])
    assert g[:, 1] == pytest.approx(200.0 - 120.0 * np.minimum((k[:14] + 1) / 10.0, 1.0))   # approach_from 1: Eq. 15


def test_prediction_commands_the_approach_profile_and_lags_less(robot):
    # the model must run the goals the controller writes: the kernel's goals are interpolated_goals'
    init, fin = np.array([RAISED] * 3), np.array([BELOW] * 3)
    a = np.array([0.5, 0.6, 0.7])
    p = predict_swing_down(robot, [1, 6, 3], init, fin, 1.0, 0.001, approach_from=a, approach_rate=0.5)
    steps = np.rint(interpolated_goals(theta_to_tick(init, robot.servo), theta_to_tick(fin, robot.servo), 1.0,
                                       0.003, p.theta_des_tick.shape[0], a, 0.5))
    assert np.array_equal(p.theta_des_tick, steps[:, :, 0])
    paper = predict_swing_down(robot, [1, 6, 3], init, fin, 1.0, 0.001)
    n = steps_to_fin(1.0 / 0.003, a, 0.5)
    assert p.reached_fin.argmax() == n - 1 and n > paper.reached_fin.argmax() + 1
    # in the slow part the lag settles to about half of the paper's (it is mostly back-EMF, so
    # proportional to the goal rate)
    for slot in range(3):
        k = int(0.9 * (a[slot] + (1 - a[slot]) / 0.5) * (1.0 / 0.003))      # late in the approach
        kp = int(0.9 / 0.003)                                                # late in the Eq. 15 swing
        assert p.err_est_tick[k, slot] < 0.7 * paper.err_est_tick[kp, slot], slot
    with pytest.raises(SwingDownError, match='approach_rate'):
        predict_swing_down(robot, [1], [RAISED], [BELOW], 1.0, 0.001, approach_from=0.5, approach_rate=0.0)
    with pytest.raises(SwingDownError, match='approach_from'):
        predict_swing_down(robot, [1], [RAISED], [BELOW], 1.0, 0.001, approach_from=1.5, approach_rate=0.5)


def _fig9(robot, t_des):
    return predict_swing_down(robot, [1, 6, 3], np.array([RAISED] * 3), np.array([BELOW] * 3), t_des, 0.001)


def test_fig9_early_peak_then_plateau_shrinking_with_t_des(robot):
    plateaus = []
    for t_des in (0.5, 1.0, 2.0):
        p = _fig9(robot, t_des)
        assert p.t_con_s == pytest.approx(0.003)
        e = p.err_est_tick[:, 0]
        t = p.t_read_s[:, 0]
        moving = ~p.reached_fin
        k_peak = int(np.argmax(e))
        assert 0.02 <= t[k_peak] <= 0.12, f't_des={t_des}: peak at {t[k_peak]:.3f} s'
        mid = moving & (t > 0.3 * t_des) & (t < 0.9 * t_des)
        plateau = float(np.median(e[mid]))
        assert np.std(e[mid]) < 0.25 * plateau + 0.2           # flat
        assert e[k_peak] > 1.3 * plateau                      # the early peak stands out
        plateaus.append(plateau)
    assert plateaus[0] > plateaus[1] > plateaus[2] > 0


def test_fig8_later_read_leg_sees_smaller_error(robot):
    p = _fig9(robot, 0.5)
    mid = (~p.reached_fin) & (p.t_read_s[:, 0] > 0.15) & (p.t_read_s[:, 0] < 0.45)
    m = p.err_est_tick[mid].mean(axis=0)
    assert m[0] > m[1] > m[2]
    assert p.t_read_s[5] == pytest.approx([0.015, 0.016, 0.017])


def test_threshold_is_estimate_plus_epsilon(robot):
    p = _fig9(robot, 1.0)
    assert p.threshold_tick == pytest.approx(p.err_est_tick + 3.0)
    assert np.all(p.direction == -1.0)        # the femur moves down: lag counted positive


def test_effects_change_the_prediction(robot):
    base = _fig9(robot, 1.0).err_est_tick[:, 0]
    heavy = robot.with_effects([Effect('mass_error', ('leg1_tibia',), {'payload_kg': 0.1})])
    sticky = robot.with_effects([Effect('static_friction', ('leg1_femur',), {'tau_s_nm': 0.3})])
    e_heavy = _fig9(heavy, 1.0).err_est_tick[:, 0]
    e_sticky = _fig9(sticky, 1.0).err_est_tick[:, 0]
    # a payload pulls the descending leg ahead of its goal (less lag); stiction delays the start
    assert e_heavy[100:250].mean() < base[100:250].mean() - 0.5
    assert e_sticky[:20].max() > base[:20].max() + 1.5


def test_bad_inputs_are_named(robot):
    with pytest.raises(SwingDownError, match='t_des_s'):
        predict_swing_down(robot, [1], [RAISED], [BELOW], 0.0, 0.001)
    with pytest.raises(SwingDownError, match='NaN'):
        predict_swing_down(robot, [1], [[np.nan, 0]], [BELOW], 1.0, 0.001)
    with pytest.raises(SwingDownError, match='no legs'):
        predict_swing_down(robot, [], [], [], 1.0, 0.001)


def test_kernel_servo_law_is_firmware_torque_nm_over_the_tick_range(robot):
    # The compiled kernel's law (servo.firmware_torque_scalar, wrapped by numba) returns the same
    # float as firmware_torque_nm for every error the firmware can see, with and without dead-band,
    # punch and a reduced torque limit.
    from hexapod_model.servo import firmware_torque_nm
    from hexapod_model.swing_common import _firmware_torque
    s = robot.servo
    err = np.arange(-s.max_tick, s.max_tick + 1, dtype=float)
    for tmax, margin, punch in ((s.stall_torque_nm, 0.0, 0.0), (s.stall_torque_nm, 2.0, 0.0), (0.4, 1.0, 0.0),
                                (0.0, 0.0, 0.0), (s.stall_torque_nm, 0.0, s.punch_nm), (0.4, 1.0, 0.2)):
        ref = firmware_torque_nm(err, 0.0, s.gain_nm_per_tick, tmax, margin, punch)
        got = np.array([_firmware_torque(e, s.gain_nm_per_tick, tmax, margin, punch) for e in err])
        assert np.array_equal(got, ref), (tmax, margin, punch)


def test_the_servo_law_has_the_ax12a_punch_outside_the_margin(robot):
    # e-manual, register 48: the punch (default 32 of 1023, the least value it takes) is the drive
    # where the error leaves the compliance margin; the slope's gain adds to it, the torque limit caps it.
    from hexapod_model.servo import firmware_torque_nm
    s = robot.servo
    assert s.punch == 32 and s.punch_nm == pytest.approx(1.5 * 32 / 1023)
    g = s.gain_nm_per_tick
    tau = firmware_torque_nm(np.array([0, 1, -1, 3, 100]), 0, g, s.stall_torque_nm, 0.0, s.punch_nm)
    np.testing.assert_allclose(tau, [0.0, s.punch_nm + g, -(s.punch_nm + g), s.punch_nm + 3 * g, s.stall_torque_nm])
    tau = firmware_torque_nm(np.array([1, 2, 3]), 0, g, s.stall_torque_nm, 2.0, s.punch_nm)
    np.testing.assert_allclose(tau, [0.0, 0.0, s.punch_nm + g])
    # the compiled model carries it: one tick of error drives a free joint harder than without punch
    from hexapod_model.swing_common import P_PUNCH2, P_PUNCH3
    from hexapod_model.swing_model import LegModel
    p = LegModel(robot, 1).params
    assert p[P_PUNCH2] == p[P_PUNCH3] == s.punch_nm


@pytest.mark.parametrize('legs', [[1], [2, 5], [1, 6, 3], [1, 2, 3, 4, 5]])
def test_fused_kernel_equals_one_rollout_per_leg(robot, legs):
    # predict_swing_down simulates every leg in one compiled call with the Eq. 15 goals expanded
    # inside; it must give what LegModel.rollout gives per leg on the goals of interpolated_goals.
    L = len(legs)
    rng = np.random.default_rng(L)
    init = np.column_stack([rng.uniform(0.2, 0.6, L), rng.uniform(-0.2, 0.4, L)])
    fin = np.column_stack([rng.uniform(-0.3, 0.0, L), rng.uniform(-0.3, 0.2, L)])
    qd0 = rng.normal(0.0, 0.2, (L, 2))
    sticky = robot.with_effects([Effect('static_friction', (f'leg{legs[0]}_femur',), {'tau_s_nm': 0.2})])
    p = predict_swing_down(sticky, legs, init, fin, 0.5, 0.001, qd0_rad_s=qd0)
    t_con = L * 0.001
    n_steps = p.theta_des_tick.shape[0]
    steps = np.rint(interpolated_goals(theta_to_tick(init, robot.servo), theta_to_tick(fin, robot.servo), 0.5,
                                       t_con, n_steps))
    for slot, leg in enumerate(legs):
        n = len(p.rollouts[slot].tau_nm)
        ro = LegModel(sticky, leg).rollout(init[slot], qd0[slot], goals_per_period(steps[:, slot], t_con, 0.001, n))
        assert np.array_equal(p.rollouts[slot].tau_nm, ro.tau_nm)
        assert np.max(np.abs(p.rollouts[slot].q_rad - ro.q_rad)) < 1e-12
        grid = np.arange(n + 1) * 0.001
        est = theta_to_tick(np.interp(p.t_read_s[:, slot], grid, ro.q_rad[:, 0]), robot.servo)
        assert np.max(np.abs(p.theta_est_tick[:, slot] - est)) < 1e-9
        assert np.array_equal(p.theta_des_tick[:, slot], steps[:, slot, 0])
    assert np.allclose(p.t_read_s, np.arange(n_steps)[:, None] * t_con + np.arange(L)[None, :] * 0.001, atol=0, rtol=0)


def test_a_batch_of_rollouts_is_each_rollout_alone_bit_for_bit(robot):
    # rollout_batch steps three rollouts side by side where LegModel.rollout steps one three times over;
    # lengths differ (the shorter ones padded), so do models (break-away friction, backlash with its
    # default gap, a coxa at two poses) and starts (one at rest on a gravity reversal)
    rng = np.random.default_rng(7)
    sticky = robot.with_effects([Effect('static_friction', ('leg2_femur',), {'tau_s_nm': 0.25}),
                                 Effect('backlash', ('leg3_tibia',), {'width_rad': 0.02})])
    coxa = CoxaModel(sticky, 4)
    cases = [(LegModel(sticky, 2), None), (LegModel(sticky, 3), None), (LegModel(robot, 1), None),
             (coxa, (0.3, -0.4)), (coxa, (-0.2, 0.5)), (LegModel(sticky, 3), None), (LegModel(sticky, 2), None)]
    params, q0, qd0, gap0, goals, alone = [], [], [], [], [], []
    for i, (model, pose) in enumerate(cases):
        n = int(rng.integers(50, 400))
        start = rng.uniform(-0.4, 0.4, 2) if i else np.zeros(2)
        g = np.rint(theta_to_tick(start + rng.uniform(-0.3, 0.3, 2), robot.servo)) + np.zeros((n, 2))
        v0 = rng.normal(0.0, 0.3, 2) if i else np.zeros(2)
        if pose is None:
            p, gap = model.params, model.start_gap_rad(start)
            ro = model.rollout(start, v0, g)
        else:
            p, gap = model.params_at(pose), np.zeros(2)
            start[1], v0[1], g[:, 1] = 0.0, 0.0, model.center_tick
            ro = CoxaModel(sticky, 4, pose).rollout_coxa(start[0], v0[0], g[:, 0])
        params.append(p), q0.append(start), qd0.append(v0), gap0.append(gap), goals.append(g), alone.append(ro.q_rad)
    got = rollout_batch(np.array(params), np.array(q0), np.array(qd0), goals, np.array(gap0))
    for q, ref in zip(got, alone):
        assert q.shape == ref.shape and np.array_equal(q, ref)
    with pytest.raises(ValueError, match='NaN'):
        rollout_batch(np.array(params[:1]), np.array([[np.nan, 0.0]]), np.array(qd0[:1]), goals[:1], np.array(gap0[:1]))


_BITS_SCRIPT = """
import hashlib, numpy as np
from hexapod_model.description import Effect, load_robot
from hexapod_model.swing_model import predict_swing_down
robot = load_robot()
worn = robot.with_effects([Effect('backlash', ('leg1_femur', 'leg1_tibia'), {'width_rad': 0.02}),
                           Effect('static_friction', ('leg6_femur',), {'tau_s_nm': 0.2})])
h = hashlib.sha256()
for r in (robot, worn):
    for legs in ([1, 6, 3], [2, 5], [4]):
        for t_des, approach in ((0.5, 1.0), (2.0, 1.0), (1.0, 0.7)):
            p = predict_swing_down(r, legs, np.array([[0.45, 0.1]] * len(legs)),
                                   np.array([[-0.15, -0.05]] * len(legs)), t_des, r.bus.t_com_s,
                                   approach_from=approach, approach_rate=0.5)
            for a in (p.theta_est_tick, p.err_est_tick, p.threshold_tick):
                h.update(np.ascontiguousarray(a).tobytes())
print(h.hexdigest())
"""


def test_a_freshly_compiled_kernel_and_the_cached_one_agree_bit_for_bit(tmp_path):
    """The same prediction from a kernel numba compiles in this process and from the one it loads
    from its cache: with fast-math 'reassoc' the two summed in different orders and the same
    trial gave different JSON in a process pool and on Ray."""
    import os
    import subprocess
    import sys
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / 'numba'))
    digests = [subprocess.run([sys.executable, '-c', _BITS_SCRIPT], env=env, capture_output=True, text=True,
                              check=True).stdout.strip() for _ in range(2)]
    assert any((tmp_path / 'numba').rglob('*.nbi'))          # the second run loaded the first one's cache
    assert len(digests[0]) == 64 and digests[0] == digests[1]
