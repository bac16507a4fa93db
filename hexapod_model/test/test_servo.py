"""The servo module's unit conversions and the AX-12A status bits, defined once."""
import itertools

import numpy as np
import pytest

from hexapod_model import servo
from hexapod_model.description import BusJoint, load_robot
from hexapod_model.servo import joint_tick_of_servo_tick, servo_theta, servo_tick, theta_to_tick, tick_to_theta


@pytest.fixture(scope='module')
def robot():
    return load_robot()


def test_error_bits_are_the_servo_status_messages():
    from hexapod_msgs.msg import ServoStatus
    names = [n for n in dir(servo) if n.startswith('ERR_')]
    assert sorted(names) == sorted(n for n in dir(ServoStatus) if n.startswith('ERR_'))
    for n in names:
        assert getattr(servo, n) == getattr(ServoStatus, n), n
    assert sorted(bit for bit, _ in servo.ERROR_BIT_NAMES) == sorted(getattr(servo, n) for n in names)
    assert servo.describe_error(servo.ERR_OVERHEATING | servo.ERR_OVERLOAD) == 'overheating, overload'
    assert servo.describe_error(0) == ''


@pytest.mark.parametrize('direction,offset', list(itertools.product((1, -1), (0, 7, -13))))
def test_joint_tick_of_servo_tick_undoes_the_mounting_exactly(robot, direction, offset):
    s = robot.servo
    bj = BusJoint('leg1_femur', 1, direction, offset)
    raw = np.arange(0, s.max_tick + 1)
    jt = joint_tick_of_servo_tick(raw, s, bj)
    assert np.array_equal(jt, np.rint(jt))                           # integers stay integers
    theta = np.array([servo_theta(float(r), s, bj) for r in raw])
    np.testing.assert_allclose(jt, theta_to_tick(theta, s), rtol=0, atol=1e-9)
    np.testing.assert_allclose(tick_to_theta(jt, s), theta, rtol=0, atol=1e-12)
    np.testing.assert_allclose([servo_tick(t, s, bj) for t in theta], raw, rtol=0, atol=1e-9)


def test_the_winding_carries_the_voltage_minus_the_back_emf():
    """Eq. 12-13: the firmware sets a voltage; a turning motor's back-EMF opposes it. At rest the
    winding carries the stall current of that voltage; at the speed where the back-EMF equals the
    voltage it carries none (the battery gives nothing); the battery's power is the copper loss plus
    the back-EMF's share, V I = I^2 R + K_t omega I; a motor the load drives against its voltage
    (braking) returns nothing to the battery."""
    from hexapod_model.servo import electrical_power_w, winding_current_a, winding_loss_w
    s = load_robot().servo
    kt = s.torque_constant_nm_per_a * s.gear_ratio
    tau = 0.6
    assert winding_current_a(tau, 0.0, s) == pytest.approx(tau / kt)
    assert electrical_power_w(tau, 0.0, s) == pytest.approx((tau / kt) ** 2 * s.winding_resistance_ohm)
    no_load = tau * s.winding_resistance_ohm / kt ** 2
    assert winding_current_a(tau, no_load, s) == pytest.approx(0.0, abs=1e-12)
    assert electrical_power_w(tau, no_load, s) == pytest.approx(0.0, abs=1e-12)
    omega = 0.4 * no_load
    i = winding_current_a(tau, omega, s)
    assert electrical_power_w(tau, omega, s) == pytest.approx(i * i * s.winding_resistance_ohm + kt * omega * i)
    assert winding_loss_w(tau, omega, s) == pytest.approx(i * i * s.winding_resistance_ohm)
    assert electrical_power_w(tau, -omega, s) > electrical_power_w(tau, 0.0, s)     # turning against the push
    assert electrical_power_w(tau, 2 * no_load, s) == 0.0                            # braking: no regeneration
    # the back-EMF damping K_t^2 / R_w is part of Table 3's B (reflected to the joint), not extra to it
    assert kt ** 2 / s.winding_resistance_ohm < s.reflected_damping_nms_per_rad
    assert winding_current_a(0.0, omega, s) == 0.0                                   # not driven: no current
