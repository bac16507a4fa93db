"""The swing-down model with the dictionary's terms (hexapod_model.swing_terms)."""
import numpy as np

from hexapod_model.description import Effect, load_robot
from hexapod_model.swing_model import CoxaModel, LegModel
from hexapod_model.swing_terms import rollout_terms


def _goals(n=2000):
    g = np.zeros((n, 2))
    g[:, 0] = 512 + np.rint(np.linspace(0, 150, n))
    g[:, 1] = 512 - np.rint(np.linspace(0, 100, n))
    return g


def test_without_terms_the_terms_kernel_is_the_fast_kernel_to_the_bit():
    m = LegModel(load_robot(), 2)
    assert not m.has_terms
    q, qd, _ = rollout_terms(m.params, m.terms, (0.0, 1.0), [0.0, 0.0], [0.0, 0.0], _goals())
    ro = m.rollout([0.0, 0.0], [0.0, 0.0], _goals())
    np.testing.assert_array_equal(q, ro.q_rad)
    np.testing.assert_array_equal(qd, ro.qd_rad_s)


def test_a_spring_holds_a_coxa_off_its_goal_by_the_torque_balance():
    """At rest the firmware torque balances the spring: punch + gain (e - margin) = k |theta - rest|."""
    robot = load_robot()
    k = 1.0
    spring = Effect('cable_spring', ('leg2_coxa',), {'stiffness_nm_per_rad': k, 'rest_angle_rad': -0.5})
    m = CoxaModel(robot.with_effects([spring]), 2)
    ro = m.rollout_coxa(0.0, 0.0, np.full(3000, 512.0))
    s = robot.servo
    err_ticks = -ro.q_rad[-1, 0] / s.rad_per_tick                  # the goal is tick 512 = 0 rad
    spring_nm = k * (ro.q_rad[-1, 0] + 0.5)
    drive_nm = s.punch_nm + s.gain_nm_per_tick * (np.rint(err_ticks) - s.compliance_margin_ticks)
    assert 1.0 < err_ticks < 20.0
    assert abs(spring_nm - drive_nm) < s.gain_nm_per_tick + s.reflected_coulomb_nm   # within a tick and friction
