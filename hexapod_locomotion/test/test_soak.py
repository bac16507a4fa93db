"""The soak run: its checks on records (plain), the emulator's fault schedule, and a 60 s run of the
real processes (realtime: the composed robot on the emulated bus with faults that come and go)."""
import json
import math
import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

import hexapod_testing as testing
from hexapod_driver.bus import EventKind
from hexapod_driver.emulator import BusEmulator
from hexapod_driver.emulator.fault_schedule import (
    KINDS,
    FaultEvent,
    ScheduleError,
    ScheduleRunner,
    dump_schedule,
    load_schedule,
    random_schedule,
)
from hexapod_locomotion.bench import soak_checks as sc

DOMAIN_ID = 180 + os.getpid() % 8           # 180..187: this file's nodes


def installed(pkg, exe):
    from ament_index_python.packages import get_package_prefix
    return os.path.join(get_package_prefix(pkg), 'lib', pkg, exe)


def _schedule(seed, duration):
    return random_schedule(seed, duration, servo_ids=range(1, 19), quiet_ids=[1, 4, 7], temperature_limit_c=70.0,
                           voltage_limits_v=(6.0, 14.0))


def test_random_schedule_is_seeded_covers_every_kind_and_ends_before_the_tail():
    a, b = _schedule(3, 1800.0), _schedule(3, 1800.0)
    assert a == b and a != _schedule(4, 1800.0)
    assert {e.kind for e in a} == set(KINDS)
    assert all(e.end_s <= 1800.0 - 10.0 for e in a)
    assert all(e.ids[0] in (1, 4, 7) for e in a if e.kind == 'silent')
    assert all(e.value > 70.0 for e in a if e.kind == 'overheat')
    assert all(not 6.0 <= e.value <= 14.0 for e in a if e.kind == 'voltage')
    assert {e.kind for e in _schedule(0, 60.0)} == set(KINDS)     # a 60 s run sees each once


def test_schedule_file_round_trip_and_bad_files(tmp_path):
    ev = _schedule(1, 120.0)
    dump_schedule(ev, tmp_path / 's.json')
    assert load_schedule(tmp_path / 's.json') == ev
    (tmp_path / 'bad.json').write_text('[{"kind": "meteor", "start_s": 1, "duration_s": 1}]')
    with pytest.raises(ScheduleError, match='meteor'):
        load_schedule(tmp_path / 'bad.json')
    (tmp_path / 'nan.json').write_text('[{"kind": "port", "start_s": NaN, "duration_s": 1}]')
    with pytest.raises(ScheduleError, match='finite'):
        load_schedule(tmp_path / 'nan.json')


def test_bus_emulator_refuses_a_bad_schedule_in_one_line(tmp_path):
    (tmp_path / 'bad.json').write_text('{"not": "a list"}')
    r = subprocess.run([sys.executable, '-m', 'hexapod_driver.emulator', '--fault-schedule', str(tmp_path / 'bad.json')],
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 2
    assert 'Traceback' not in r.stderr and 'JSON list' in r.stderr


def test_schedule_runner_applies_and_ends_each_fault(tmp_path):
    """Through the emulator object: every fault starts, ends, and leaves the bus as it was."""
    events = [FaultEvent('drop', 0.0, 0.05, (3,), 1.0), FaultEvent('overheat', 0.0, 0.05, (5,), 80.0),
              FaultEvent('voltage', 0.0, 0.05, (), 15.0), FaultEvent('silent', 0.0, 0.05, (7,)),
              FaultEvent('port', 0.0, 0.05)]
    with BusEmulator() as emu:
        runner = ScheduleRunner(emu, events, tmp_path / 'ev.jsonl')
        runner.begin()
        runner._thread.join(timeout=10.0)
        runner.close()
        recs = [json.loads(x) for x in (tmp_path / 'ev.jsonl').read_text().splitlines()]
        assert sum(r['phase'] == 'start' for r in recs) == sum(r['phase'] == 'end' for r in recs) == 5
        assert not emu.faults._drop and not emu.faults.missing and not emu.faults.temperature_override
        assert all(s.voltage_v == emu.robot.servo.supply_voltage_v for s in emu.servos)
        assert emu._master is not None                           # the port is back


def test_invented_positions_are_caught():
    reported = {1: np.array([500, 501, 502, 503, 501]), 2: np.array([10, 11])}
    assert sc.invented_positions({1: np.array([501, 503, 501]), 2: np.array([11])}, reported) == (0, [])
    bad, ex = sc.invented_positions({1: np.array([501, 504])}, reported)       # 504 never reported
    assert bad == 1 and '504' in ex[0]
    bad, _ = sc.invented_positions({1: np.array([503, 500])}, reported)        # 500 only before 503
    assert bad == 1
    bad, _ = sc.invented_positions({1: np.array([500, 512, 501, 502])}, reported)   # one foreign message:
    assert bad == 1                                                                  # the rest still match


def _status(t, name, level=0, message='OK', **values):
    return {'t': t, 'name': name, 'level': level, 'message': message, 'values': {k: str(v) for k, v in values.items()}}


def test_judge_faults_needs_the_report_and_the_recovery():
    servo = 'hexapod_driver: servo leg3_coxa (id 7)'
    faults = [{'fault': 0, 'kind': 'silent', 'ids': [7], 'value': 0.0, 'duration_s': 2.0, 'start': 10.0, 'end': 12.0}]
    quiet = [_status(11.0, servo, responding='true'), _status(13.0, servo, responding='true')]
    v, = sc.judge_faults(faults, quiet, [7], 20.0, 'recover')
    assert not v.seen
    told = [_status(11.0, servo, 2, 'not responding', responding='false')]
    v, = sc.judge_faults(faults, told, [7], 20.0, 'recover')
    assert v.seen and v.recovered is False
    v, = sc.judge_faults(faults, told + [_status(13.0, servo, responding='true')], [7], 20.0, 'recover')
    assert v.seen and v.recovered
    # silent while the driver sent it nothing: not observable; asked and unanswered: must be reported
    v, = sc.judge_faults(faults, quiet, [7], 20.0, 'recover', asked={7: np.array([3.0, 15.0])})
    assert v.seen is None
    v, = sc.judge_faults(faults, quiet, [7], 20.0, 'recover', asked={7: np.array([11.0])})
    assert v.seen is False
    port = [{'fault': 1, 'kind': 'port', 'ids': [], 'value': 0.0, 'duration_s': 0.5, 'start': 5.0, 'end': 5.5}]
    bus = 'hexapod_driver: bus'
    v, = sc.judge_faults(port, [_status(5.2, bus, 2, 'port lost: gone', reads=0),
                                _status(6.5, bus, 0, 'OK', reads=300)], [7], 20.0, 'recover')
    assert v.seen and v.recovered


def test_control_periods_and_windows():
    reads = [(1, 0.0, 0.0), (1, 0.0, 0.003), (1, 0.0, 0.006), (2, 0.0, 0.001), (2, 0.0, 0.005), (1, 1.0, 1.0)]
    t, p = sc.control_periods(reads)
    assert np.allclose(sorted(p), [0.003, 0.003, 0.004])
    w = sc.windows(np.array([1.0, 2.0, 61.0]), np.array([0.003, 0.005, 0.004]), 0.0, 60.0)
    assert [n for _, n, _, _ in w] == [2, 1] and math.isclose(w[0][2], 0.004)
    assert not sc.drift(w[0], (60.0, 10, 0.0050, 0.0050), 0.10).ok
    assert sc.drift((0, 10, 0.004, 0.005), (60.0, 10, 0.0041, 0.0052), 0.10).ok


@pytest.mark.realtime
def test_soak_one_minute(tmp_path):
    """The real processes for 60 s. The functional checks are asserted from the report and the logs;
    timing figures are printed (a loaded machine moves them), not judged."""
    out = tmp_path / 'soak'
    env = dict(os.environ, ROS_DOMAIN_ID=str(DOMAIN_ID), ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST',
               PYTHONUNBUFFERED='1')
    r = subprocess.run([sys.executable, installed('hexapod_locomotion', 'soak'), '--minutes', '1', '--seed', '0',
                        '--out', str(out)], env=env, capture_output=True, text=True, timeout=600)
    print(r.stdout[-6000:])
    report = (out / 'report.txt').read_text()
    assert 'Traceback' not in r.stdout + r.stderr
    for check in ('one /joint_states publisher', 'faults reported', 'faults recovered', 'torque off at the end', 'robot exit code',
                  'bag readable', 'bag up to the end', 'no invented positions'):
        assert f'PASS  {check}' in report, f'{check} did not pass:\n{report}'
    assert r.returncode == 0, report
    assert 'control period per' in report and 'reads:' in report and 'CPU s/s' in report
    # what happened is in the logs too: the port loss and its return, a servo that went silent and came back
    robot_log = (out / 'robot.log').read_text()
    for kind in (EventKind.PORT_LOST, EventKind.RECONNECTED, EventKind.SERVO_MISSING, EventKind.SERVO_ANSWERS):
        assert testing.logged(robot_log, kind), f'no {kind.tag} event in the robot log'
    assert 'torque off on all servos (read back)' in robot_log
    diags = [json.loads(x) for x in (out / 'diagnostics.jsonl').read_text().splitlines()]
    assert any('port lost' in d['message'] for d in diags)


@pytest.mark.realtime
def test_soak_ctrl_c_ends_with_the_report_so_far(tmp_path):
    """Ctrl-C while walking: the robot, the recorder and the bus stop in that order, the report of
    the run so far is printed, torque is off, the bag is readable, nothing is left running."""
    out = tmp_path / 'soak'
    env = dict(os.environ, ROS_DOMAIN_ID=str(DOMAIN_ID), ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST',
               PYTHONUNBUFFERED='1')
    proc = subprocess.Popen([sys.executable, installed('hexapod_locomotion', 'soak'), '--minutes', '5', '--out', str(out)],
                            env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    lines = []
    for line in proc.stdout:                 # until walking has started and one fault has come
        lines.append(line)
        if 'walking from' in line:
            break
    t_fail = time.monotonic() + 120.0         # a failure bound; the condition is what the soak has logged
    diag = out / 'diagnostics.jsonl'
    while not (diag.exists() and diag.read_text().count('\n') >= 200):
        assert time.monotonic() < t_fail and proc.poll() is None, ''.join(lines)
        time.sleep(0.2)
    proc.send_signal(signal.SIGINT)
    rest, _ = proc.communicate(timeout=180)
    text = ''.join(lines) + rest
    assert 'Traceback' not in text, text
    assert 'Ctrl-C' in text and 'soak report' in text and '(interrupted)' in text, text
    assert 'PASS  torque off at the end' in text, text
    assert 'PASS  bag readable' in text and 'PASS  no invented positions' in text, text
    assert 'did not stop' not in text, text          # each child ended on its signal, none was killed


def test_a_drop_or_corruption_that_drew_no_request_is_not_observable():
    """Replies dropped or corrupted with p = 0.2 on a servo read 9 times in the fault's seconds: 13 % of
    such faults touch no reply at all, and then the driver has nothing to report."""
    bus = 'hexapod_driver: bus'
    quiet = [_status(11.0, bus, 0, 'OK', reads=300, failed_reads=0),
             _status(13.0, 'hexapod_driver: servo leg3_coxa (id 7)', responding='true')]
    for kind, spoiled in (('drop', 'asked'), ('corrupt', 'corrupted')):
        fault = [{'fault': 0, 'kind': kind, 'ids': [7], 'value': 0.2, 'duration_s': 2.0, 'start': 10.0, 'end': 12.0}]
        v, = sc.judge_faults(fault, quiet, [7], 20.0, 'recover', **{spoiled: {7: np.array([3.0, 15.0])}})
        assert v.seen is None, kind
        v, = sc.judge_faults(fault, quiet, [7], 20.0, 'recover', **{spoiled: {7: np.array([11.0])}})
        assert v.seen is False, kind                                  # it drew one: the driver must say so
        told = quiet + [_status(11.5, bus, 1, 'failed reads', reads=300, failed_reads=1)]
        v, = sc.judge_faults(fault, told, [7], 20.0, 'recover', **{spoiled: {7: np.array([11.0])}})
        assert v.seen and v.recovered
