"""The servo module's unit conversions and the AX-12A status bits, defined once."""
import itertools

import numpy as np
import pytest

from hexapod_model import servo
from hexapod_model.description import BusJoint, load_robot
from hexapod_model.servo import (joint_tick_of_servo_tick, servo_theta, servo_tick, theta_to_tick,
                                 tick_to_theta)


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
