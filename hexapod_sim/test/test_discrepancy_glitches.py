"""Physically impossible reads (a stamp a second off, a corrupt position) are reported and left out:
the tool finds the same effect with them as without them."""
import json
import math

import numpy as np
import pytest
from synthetic import model_recording

from hexapod_model.contract import JOINT_COMMANDS, JOINT_STATES, MSG_TYPES
from hexapod_model.description import Effect, load_robot
from hexapod_model.joints import JOINTS, Joint
from hexapod_sim.bagio import BagWriter
from hexapod_sim.calibration.plan import calibration_plan
from hexapod_sim.discrepancy.analysis import analyse
from hexapod_sim.discrepancy.cli import main
from hexapod_sim.discrepancy.glitches import GlitchSettings, no_load_speed_rad_s, screen
from hexapod_sim.discrepancy.recording import Recording, load_recording

WIDTH = math.radians(1.3)
JOINT = Joint(5, 'tibia')


@pytest.fixture(scope='module')
def robot():
    return load_robot()


@pytest.fixture(scope='module')
def clean(robot):
    truth = Effect('backlash', (JOINT,), {'width_rad': WIDTH})
    return model_recording(robot.with_effects([truth]), calibration_plan(robot, legs=(5,), phases=('tibia',)))


def _msg(t_ns, names, values):
    return {'header': {'stamp': {'sec': t_ns // 1_000_000_000, 'nanosec': t_ns % 1_000_000_000}, 'frame_id': ''},
            'name': list(names), 'position': list(values), 'velocity': [], 'effort': []}


def write_with_glitches(rec: Recording, path, stamp_shift: dict, value_shift: dict, t0_ns=1_700_000_000_000_000_000):
    """Write ``rec`` as a bag; reads of JOINT by index get their header stamp shifted [s] (record time
    unchanged) or their position shifted [rad]."""
    events = []
    writes = {}
    for j, s in rec.commands.items():
        for t, v in zip(s.t_s, s.theta_rad):
            writes.setdefault(float(t), {})[j] = float(v)
    for t, goals in writes.items():
        joints = [j for j in JOINTS if j in goals]
        events.append((t, 0, JOINT_COMMANDS, [str(j) for j in joints], [goals[j] for j in joints], 0.0))
    for j, s in rec.states.items():
        for i, (t, v) in enumerate(zip(s.t_s, s.theta_rad)):
            dv = value_shift.get(i, 0.0) if j == JOINT else 0.0
            dt = stamp_shift.get(i, 0.0) if j == JOINT else 0.0
            events.append((float(t), 1, JOINT_STATES, [str(j)], [float(v) + dv], dt))
    events.sort(key=lambda e: (e[0], e[1]))
    w = BagWriter(str(path), flush_period_s=60.0)
    try:
        for t, _, topic, names, values, dt in events:
            log_ns = t0_ns + int(round(t * 1e9))
            w.write(topic, MSG_TYPES[topic], _msg(log_ns + int(round(dt * 1e9)), names, values), log_ns)
    finally:
        w.close()


def test_screen_finds_each_kind_and_nothing_in_clean_motion(robot):
    servo = robot.servo
    t = np.arange(0.0, 2.0, 0.006)
    theta = 0.8 * np.sin(2 * np.pi * 0.7 * t)            # 3.5 rad/s peak: fast, but what a servo can do
    assert 0.8 * 2 * np.pi * 0.7 < no_load_speed_rad_s(servo)
    log = t + 0.002
    rows = {JOINT: np.column_stack([t, theta, log])}
    kept, found = screen(rows, 'read', servo)
    assert found == [] and len(kept[JOINT]) == len(t)
    a = np.column_stack([t, theta, log])
    a[50, 0] += 1.0                                       # stamp one second late
    a[120, 0] -= 0.5                                      # stamp runs back: out of order
    a[200, 1] += 0.9                                      # corrupt position (175 ticks)
    a[260, 1] = 3.0                                       # outside the servo's 300 degrees
    kept, found = screen({JOINT: a}, 'read', servo)
    kinds = sorted(k for _, _, k, _ in found)
    assert kinds == ['out_of_order', 'out_of_range', 'speed', 'stamp_jump']
    assert len(kept[JOINT]) == len(t) - 4
    # without record times the stamp glitches show as position jumps of the moving joint
    b = a[:, :2].copy()
    kept, found = screen({JOINT: b}, 'read', servo, GlitchSettings())
    assert len(found) == 4 and len(kept[JOINT]) == len(t) - 4
    # delivery latency (record time after the stamp, up to max_latency_s) is no glitch: a stall
    # delivers 40 reads late, all at once with the next one
    c = np.column_stack([t, theta, log])
    c[100:140, 2] = c[140, 2]
    assert screen({JOINT: c}, 'read', servo)[1] == []


def test_glitched_reads_are_reported_and_do_not_change_the_effect(robot, clean, tmp_path, capsys):
    n = len(clean.states[JOINT])
    stamp_shift = {n // 5: 1.0, n // 3: -0.7}
    value_shift = {n // 2: 0.9, (2 * n) // 3: -0.6}
    write_with_glitches(clean, tmp_path / 'clean', {}, {})
    write_with_glitches(clean, tmp_path / 'glitched', stamp_shift, value_shift)
    docs = {}
    for name in ('clean', 'glitched'):
        out = tmp_path / f'{name}.json'
        assert main([str(tmp_path / name), '--json', str(out), '--no-progress']) == 0
        docs[name] = json.loads(out.read_text())
    text = capsys.readouterr().out
    assert '4 physically impossible sample(s) left out of the analysis' in text
    assert docs['clean']['glitches'] == []
    g = docs['glitched']['glitches']
    assert len(g) == 4 and {x['joint'] for x in g} == {str(JOINT)} and {x['topic'] for x in g} == {'read'}
    assert sorted(x['kind'] for x in g) == ['out_of_order', 'speed', 'speed', 'stamp_jump']
    (a,), (b,) = docs['clean']['effects'], docs['glitched']['effects']
    assert a['effect'] == b['effect'] == 'backlash' and a['joints'] == b['joints'] == [str(JOINT)]
    assert b['params']['width_rad'] == pytest.approx(a['params']['width_rad'], rel=0.05)
    assert b['params']['width_rad'] == pytest.approx(WIDTH, rel=0.15)


def test_the_same_glitches_left_in_would_mislead_the_fit(robot, clean, tmp_path):
    """The screen matters: fed to the fit unscreened, two corrupt reads move the held-out error."""
    write_with_glitches(clean, tmp_path / 'glitched', {}, {len(clean.states[JOINT]) // 2: 0.9,
                                                           (2 * len(clean.states[JOINT])) // 3: -0.9})
    screened = load_recording(tmp_path / 'glitched', robot)
    assert len(screened.glitches) == 2
    s = clean.states[JOINT]
    theta = s.theta_rad.copy()
    theta[len(theta) // 2] += 0.9
    theta[(2 * len(theta)) // 3] -= 0.9
    raw = Recording(commands=clean.commands, states={JOINT: type(s)(s.t_s, theta)}, source='unscreened')
    with_glitches = analyse(raw, robot)
    without = analyse(screened, robot)
    assert without.joints[JOINT].heldout_rmse_ticks_after < 1.0
    assert with_glitches.joints[JOINT].heldout_rmse_ticks_after > 2 * without.joints[JOINT].heldout_rmse_ticks_after
