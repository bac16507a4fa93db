"""Servo state and bus health -> standard diagnostics (levels, keys, message text)."""
import math

import pytest

from hexapod_model import diagnostics as dg
from hexapod_model.description import load_robot


@pytest.fixture(scope='module')
def robot():
    return load_robot()


def servo(robot, **kw):
    args = dict(temperature_c=38.0, voltage_v=12.1, load_fraction=-0.25, error_bits=0, responding=True,
                torque_enabled=True, torque_limit=1023)
    args.update(kw)
    return dg.servo_status(robot, 'hexapod_driver', 'leg2_tibia', 6, **args)


def test_healthy_servo_is_ok_with_its_key_values(robot):
    s = servo(robot)
    assert (s.level, s.message) == (dg.OK, 'OK')
    assert s.name == 'hexapod_driver: servo leg2_tibia (id 6)' and s.hardware_id == 'dynamixel id 6'
    v = dict(s.values)
    assert v['temperature_c'] == '38.0' and v['voltage_v'] == '12.1' and v['load_percent'] == '-25'
    assert v['error_bits'] == '0x00' and v['torque_limit'] == '100%' and v['torque_enabled'] == 'true'


@pytest.mark.parametrize('kw, level, text', [
    (dict(responding=False), dg.ERROR, 'not responding'),
    (dict(error_bits=4, torque_limit=0), dg.ERROR, 'overheating error'),
    (dict(error_bits=32), dg.ERROR, 'overload error'),
    (dict(error_bits=1), dg.ERROR, 'input voltage error'),
    (dict(torque_limit=0), dg.ERROR, 'alarm shutdown'),
    (dict(error_bits=2), dg.WARN, 'angle limit error'),
    (dict(error_bits=16), dg.WARN, 'checksum error'),
    (dict(torque_enabled=False), dg.WARN, 'torque off'),
])
def test_servo_levels(robot, kw, level, text):
    s = servo(robot, **kw)
    assert s.level == level and text in s.message, s


def test_temperature_levels_follow_the_descriptions_shutdown_temperature(robot):
    shutdown = robot.servo.shutdown_temperature_c
    assert servo(robot, temperature_c=shutdown - dg.TEMPERATURE_WARN_MARGIN_K - 0.1).level == dg.OK
    warm = servo(robot, temperature_c=shutdown - dg.TEMPERATURE_WARN_MARGIN_K + 0.1)
    assert warm.level == dg.WARN and 'of shutdown' in warm.message
    assert servo(robot, temperature_c=shutdown).level == dg.ERROR


def test_unknown_values_say_so_and_the_worst_problem_sets_the_level(robot):
    s = servo(robot, temperature_c=math.nan, voltage_v=math.nan, load_fraction=math.nan, torque_limit=None,
              error_bits=2 | 4, note='fault policy: torque off')
    v = dict(s.values)
    assert v['temperature_c'] == v['voltage_v'] == v['load_percent'] == v['torque_limit'] == 'unknown'
    assert v['error_bits'] == '0x06 (angle limit, overheating)'
    assert s.level == dg.ERROR and s.message.endswith('(fault policy: torque off)')
    assert 'angle limit error' in s.message and 'overheating error' in s.message


def bus(robot, **kw):
    args = dict(window_s=1.0, reads=950, failed_reads=0, t_com_mean_s=robot.bus.t_com_s, t_com_p99_s=0.0012,
                t_com_max_s=0.002, write_mean_s=0.0004)
    args.update(kw)
    return dg.bus_status(robot, 'hexapod_driver', **args)


def test_bus_health(robot):
    ok = bus(robot)
    assert ok.level == dg.OK and ok.name == 'hexapod_driver: bus' and ok.message == 'OK: 950 reads/s'
    v = dict(ok.values)
    assert v['read_rate_hz'] == '950.0' and v['t_com_mean_ms'] == '1.000' and v['t_com_model_ms'] == '1'
    assert bus(robot, failed_reads=3).level == dg.WARN
    assert bus(robot, reads=0, failed_reads=5, t_com_mean_s=math.nan).level == dg.ERROR
    idle = bus(robot, reads=0, t_com_mean_s=math.nan)
    assert idle.level == dg.WARN and 'no read' in idle.message and dict(idle.values)['t_com_mean_ms'] == 'unknown'
    slow = bus(robot, t_com_mean_s=0.016)                   # a stock USB adapter: Eq. 17 timing is off
    assert slow.level == dg.WARN and '16.0 ms' in slow.message
    assert bus(robot, note='watchdog').level == dg.ERROR


def test_ros_message_and_bag_dict(robot):
    pytest.importorskip('diagnostic_msgs')
    from builtin_interfaces.msg import Time
    statuses = [servo(robot, responding=False), bus(robot)]
    msg = dg.diagnostic_array(statuses, Time(sec=3, nanosec=5))
    assert [s.level for s in msg.status] == [bytes([dg.ERROR]), bytes([dg.OK])]
    assert msg.status[0].values[2].key == 'temperature_c' and msg.header.stamp.sec == 3
    d = dg.array_dict(statuses, 3.000000005)
    assert d['header']['stamp'] == {'sec': 3, 'nanosec': 5} and d['status'][0]['level'] == dg.ERROR
