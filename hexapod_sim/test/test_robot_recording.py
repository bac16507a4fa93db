"""The real-robot recording commands against the emulated bus: `stand_calibration` runs the routine on
the driver and writes a contract bag; `record_contract` records a running driver_node's topics into one.

DDS stays on loopback (ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST) on a domain of its own.
"""
import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

import hexapod_testing as testing
from hexapod_driver.emulator import BusEmulator
from hexapod_model.description import load_robot
from hexapod_model.joints import JOINTS, LEG_JOINTS, Joint
from hexapod_sim.calibration.stand import main as stand_calibration
from hexapod_sim.discrepancy.recording import load_recording

DOMAIN_ID = 40 + os.getpid() % 20          # 40..59: clear of test_driver_node's 20..39


@pytest.fixture(scope='module')
def robot():
    return load_robot()


def test_stand_calibration_runs_the_routine_on_the_driver_and_writes_the_contract_bag(robot, tmp_path, capsys):
    bag = tmp_path / 'stand'
    with BusEmulator(robot) as emu:
        assert stand_calibration(['--device', emu.port, '--out', str(bag), '--legs', '2', '--phases', 'settle',
                                  '--no-progress']) == 0
        # the routine's goals reached the servos of leg 2 (ids 4-6): the settle pose
        from hexapod_sim.calibration.plan import calibration_plan
        plan = calibration_plan(robot, legs=(2,), phases=('settle',))
        goal_femur = round(512 + plan.goals_rad[0, 1] / robot.servo.rad_per_tick)
        assert emu.servo(5).get('goal_position') == goal_femur
    assert 'wrote' in capsys.readouterr().out
    rec = load_recording(bag, robot)
    assert rec.joints == LEG_JOINTS[2]
    assert rec.glitches == ()
    for j in rec.joints:
        s = rec.states[j]
        assert len(s) >= 20 and np.all(np.diff(s.t_s) > 0)
        assert np.all(np.abs(s.theta_rad) < 2.7)


def test_stand_calibration_names_bad_input_and_leaves_nothing(robot, tmp_path, capsys):
    bag = tmp_path / 'none'
    assert stand_calibration(['--device', str(tmp_path / 'no_such_tty'), '--out', str(bag), '--no-progress']) == 2
    err = capsys.readouterr().err
    assert 'stand_calibration: error:' in err and 'no_such_tty' in err and 'Traceback' not in err
    assert not bag.exists()
    (tmp_path / 'taken').mkdir()
    with pytest.raises(SystemExit) as exc:
        stand_calibration(['--out', str(tmp_path / 'taken')])
    assert exc.value.code == 2
    assert 'already exists' in capsys.readouterr().err


def _env():
    return testing.node_env(DOMAIN_ID)


@pytest.mark.realtime      # the driver reads and the publisher writes in wall time for a few seconds: a loaded machine gets fewer messages
def test_record_contract_records_the_driver_topics_into_a_contract_bag(robot, tmp_path):
    pytest.importorskip('rclpy')
    bag = tmp_path / 'rec'
    with BusEmulator(robot) as emu:
        driver = subprocess.Popen([sys.executable, '-m', 'hexapod_driver.driver_node', '--ros-args',
                                   '-p', f'device:={emu.port}', '-p', 'read_period_s:=0.005',
                                   '-p', 'command_timeout_s:=0.0', '-p', 'timeout_margin_ms:=25.0',
                                   '-p', 'startup_timeout_margin_ms:=200.0', '-p', 'startup_attempts:=10'],
                                  env=_env(), stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        rec = subprocess.Popen([sys.executable, '-m', 'hexapod_sim.bagio.record_contract', '--out', str(bag)],
                               env=_env(), stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        try:
            import rclpy
            from sensor_msgs.msg import JointState
            ctx = rclpy.Context()
            rclpy.init(context=ctx, domain_id=DOMAIN_ID)
            node = rclpy.create_node('record_contract_test', context=ctx)
            pub = node.create_publisher(JointState, '/joint_commands', 10)
            n_sent = 0
            t_end = time.monotonic() + 60.0
            # commands until the recorder has seen reads and commands (discovery takes a while)
            while time.monotonic() < t_end and n_sent < 400:
                assert driver.poll() is None, driver.communicate()[0]
                assert rec.poll() is None, rec.communicate()[0]
                msg = JointState()
                msg.header.stamp = node.get_clock().now().to_msg()
                msg.name, msg.position = ['leg1_coxa'], [0.2 * np.sin(n_sent * 0.05)]
                pub.publish(msg)
                n_sent += 1
                time.sleep(0.02)
            node.destroy_node()
            rclpy.try_shutdown(context=ctx)
        finally:
            rc, out = testing.stop_process(rec, signal.SIGTERM)
            testing.stop_process(driver)
    assert rc == 0, out
    assert 'wrote' in out
    r = load_recording(bag, robot)
    assert set(r.states) == set(JOINTS)                   # the driver's default schedule reads all 18
    assert len(r.commands[Joint(1, 'coxa')]) >= 50
    assert r.glitches == ()
    s = r.states[Joint(1, 'femur')]
    assert len(s) >= 20 and np.all(np.diff(s.t_s) > 0)


def test_record_contract_names_bad_input(tmp_path):
    (tmp_path / 'taken').mkdir()
    p = subprocess.run([sys.executable, '-m', 'hexapod_sim.bagio.record_contract', '--out', str(tmp_path / 'taken')],
                       env=_env(), capture_output=True, text=True, timeout=60)
    assert p.returncode == 2 and 'already exists' in p.stderr and 'Traceback' not in p.stderr
    p = subprocess.run([sys.executable, '-m', 'hexapod_sim.bagio.record_contract', '--out', str(tmp_path / 'x'),
                        '--duration', 'nan'], env=_env(), capture_output=True, text=True, timeout=60)
    assert p.returncode == 2 and '--duration' in p.stderr and not (tmp_path / 'x').exists()
