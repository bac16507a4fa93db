"""The discrepancy command line on a bag: JSON, plot, overlay that closes the loop, named errors,
and the choice of free-leg spans (stand, walk, --time)."""
import json
import math
from dataclasses import replace

import numpy as np
import pytest
from synthetic import model_recording

from hexapod_model.description import JOINT_ROLES, Effect, load_robot
from hexapod_model.joints import Joint
from hexapod_sim.bagio import BagWriter
from hexapod_sim.calibration.plan import calibration_plan
from hexapod_sim.discrepancy.cli import main
from hexapod_sim.discrepancy.recording import Recording, RecordingError, load_recording
from hexapod_sim.discrepancy.segments import looks_like_walk, parse_windows, swing_segments
from hexapod_sim.discrepancy.simulate import Replay

WIDTH = math.radians(1.3)


@pytest.fixture(scope='module')
def robot():
    return load_robot()


@pytest.fixture(scope='module')
def bag(robot, tmp_path_factory):
    truth = Effect('backlash', ('leg5_tibia',), {'width_rad': WIDTH})
    rec = model_recording(robot.with_effects([truth]), calibration_plan(robot, legs=(5,), phases=('tibia',)))
    path = tmp_path_factory.mktemp('bags') / 'backlash_leg5'
    rec.write_bag(path)
    return path, rec


def test_bag_round_trip_keeps_every_write_and_read(bag):
    path, rec = bag
    back = load_recording(path)
    assert back.joints == rec.joints
    for j in rec.joints:
        assert np.allclose(back.states[j].t_s, rec.states[j].t_s, atol=1e-6)
        assert np.allclose(back.states[j].theta_rad, rec.states[j].theta_rad, atol=1e-12)
        assert np.allclose(back.commands[j].theta_rad, rec.commands[j].theta_rad, atol=1e-12)


def test_cli_writes_json_plot_overlay_and_the_overlay_closes_the_loop(bag, tmp_path, capsys):
    path, _ = bag
    out_json, out_png, out_yaml = tmp_path / 'r.json', tmp_path / 'r.png', tmp_path / 'fit.yaml'
    assert main([str(path), '--json', str(out_json), '--plot', str(out_png), '--write-overlay', str(out_yaml),
                 '--no-progress']) == 0
    text = capsys.readouterr().out
    assert 'leg 5 tibia: the simulation left out gear backlash of about' in text
    doc = json.loads(out_json.read_text())
    assert doc['bag'] == str(path)
    (eff,) = doc['effects']
    assert eff['effect'] == 'backlash' and eff['joints'] == ['leg5_tibia']
    assert eff['params']['width_rad'] == pytest.approx(WIDTH, rel=0.15)
    assert eff['heldout_rmse_ticks_before'] / eff['heldout_rmse_ticks_after'] >= 1.5
    assert doc['joints']['leg5_tibia']['heldout_rmse_ticks_after'] < doc['joints']['leg5_tibia'][
        'heldout_rmse_ticks_before']
    assert all(set(m) - {'phase'} == {'joint', 't_start', 't_end', 'condition', 'rmse_ticks', 'peak_rmse_ticks'}
               for m in doc['mismatches'])
    # a window is flagged by its peak sliding-window RMS, beyond the 0.75-tick threshold
    assert all(m['peak_rmse_ticks'] > 0.75 for m in doc['mismatches'])
    assert out_png.read_bytes()[:8] == b'\x89PNG\r\n\x1a\n'
    # the overlay is a robot description overlay the model (and the sim) accept ...
    fitted = load_robot(overlays=[out_yaml])
    assert fitted.joint_effects('leg5_tibia').backlash_width_rad == pytest.approx(eff['params']['width_rad'])
    # ... and with it the same recording has nothing left to explain
    assert main([str(path), '--overlay', str(out_yaml), '--json', str(out_json), '--no-progress']) == 0
    assert json.loads(out_json.read_text())['effects'] == []
    assert 'No missing physics found' in capsys.readouterr().out


def test_cli_names_bad_input(bag, tmp_path, capsys):
    path, _ = bag
    assert main([str(tmp_path / 'nope'), '--no-progress']) == 2
    assert 'no such bag' in capsys.readouterr().err
    assert main([str(path), '--joints', 'leg9_femur', '--no-progress']) == 2
    assert 'unknown joint' in capsys.readouterr().err
    assert main([str(path), '--joints', 'leg1_femur', '--no-progress']) == 2
    assert 'not read' in capsys.readouterr().err
    assert main([str(path), '--time', '5', '--no-progress']) == 2
    assert 'START:END' in capsys.readouterr().err
    only_states = tmp_path / 'states_only'
    with BagWriter(str(only_states)) as w:
        w.write('/joint_states', 'sensor_msgs/msg/JointState',
                {'header': {'stamp': {'sec': 1, 'nanosec': 0}, 'frame_id': ''}, 'name': ['leg1_femur'],
                 'position': [0.1], 'velocity': [], 'effort': []}, 1_000_000_000)
    assert main([str(only_states), '--no-progress']) == 2
    assert 'no /joint_commands' in capsys.readouterr().err


def test_a_truncated_bag_is_analysed_as_far_as_it_goes_with_one_warning_line(bag, tmp_path, capsys):
    """A bag cut off mid-chunk (a crash while recording): the tool reads the messages that are
    complete, says so in one line naming the file, and analyses them; no Python warning text."""
    import shutil
    path, _ = bag
    cut = tmp_path / 'cut'
    shutil.copytree(path, cut)
    mcap = next(cut.glob('*.mcap'))
    data = mcap.read_bytes()
    mcap.write_bytes(data[:int(len(data) * 0.6)])
    assert main([str(cut), '--no-progress']) == 0
    out, err = capsys.readouterr()
    lines = err.strip().splitlines()
    assert len(lines) == 1 and ': warning: ' in lines[0] and mcap.name in lines[0] and 'truncated' in lines[0], err
    assert 'BagWarning' not in err and 'discrepancy report' in out


def test_time_windows_restrict_the_analysis(bag, robot):
    from hexapod_sim.discrepancy import analyse
    _, rec = bag
    a = analyse(rec, robot, windows=parse_windows(['2:6', '9:12']), workers=1)
    t = a.replay.reads[Joint(5, 'tibia')].t_s
    assert t.min() >= 2.0 and t.max() <= 12.0 and not np.any((t > 6.0) & (t < 9.0))
    assert a.mode == 'windows'


def _walk_like(robot, stance_offset_ticks):
    """Two legs in turn (leg 2 half a cycle later: a gait keeps a leg on the ground): femur lifted
    (swing) then lowered and held while reads sit above the goal (stance)."""
    dt = 0.003
    t = np.arange(0.0, 6.0, dt)
    cmds, reads = [], []
    for k, tt in enumerate(t):
        # per leg: 0-0.5 hold, 0.5-1 lift, 1-1.5 hold up, 1.5-2 lower, 2-3 stance
        phase = {leg: (tt - 1.5 * (leg - 1)) % 3.0 for leg in (1, 2)}
        femur = {leg: 0.3 * np.clip((p - 0.5) / 0.5, 0, 1) - 0.3 * np.clip((p - 1.5) / 0.5, 0, 1)
                 for leg, p in phase.items()}
        goals = {f'leg{leg}_{r}': (femur[leg] if r == 'femur' else 0.0) for leg in (1, 2) for r in JOINT_ROLES}
        cmds.append((tt, goals))
        for leg in (1, 2):
            stance = phase[leg] < 0.5 or phase[leg] > 2.05
            off = stance_offset_ticks * robot.servo.rad_per_tick if stance else 0.0
            reads.append((tt + 0.001 * leg, f'leg{leg}_femur', femur[leg] + off))
    return Recording.from_samples(cmds, reads)


def _looks_like_walk(robot, rec):
    rep = Replay(robot, rec)
    pred = rep.predict(robot)
    return looks_like_walk(rep, {j: rep.reads[j].tick - pred[j] for j in rep.joints}, swing_segments(rec, rep.legs),
                           imu=rec.imu)


def test_walk_is_recognised_from_legs_pushed_up_outside_their_swings(robot):
    walk = _walk_like(robot, stance_offset_ticks=12)
    assert _looks_like_walk(robot, walk)
    hanging = _walk_like(robot, stance_offset_ticks=-2)
    assert not _looks_like_walk(robot, hanging)
    spans = swing_segments(walk, (1, 2))
    assert len(spans[1]) == 2
    for a, b in spans[1]:
        cycle = np.floor(a / 3.0) * 3.0
        assert a == pytest.approx(cycle + 0.5 + 0.08, abs=0.02)     # lift start + settle
        assert b == pytest.approx(cycle + 2.0 - 0.1, abs=0.02)      # swing-down stop - margin


def _imu(rec, rate_rms_rad_s, seed=0):
    """/imu at 400 Hz over ``rec``: gravity, and a body rocking about x at 1.5 Hz with the given RMS rate
    plus a gyro's noise (0.002 rad/s RMS) and bias."""
    from hexapod_model.imu import ImuSeries
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, 6.0, 0.0025)
    gyro = rng.normal(0.0, 0.002 / np.sqrt(3), (len(t), 3)) + np.array([0.01, -0.02, 0.005])
    gyro[:, 0] += rate_rms_rad_s * np.sqrt(2) * np.sin(2 * np.pi * 1.5 * t)
    accel = np.tile([0.0, 0.0, 9.81], (len(t), 1))
    return replace(rec, imu=ImuSeries(t, accel, gyro))


def test_walk_whose_femurs_hide_the_load_is_recognised_from_the_body_rocking_on_imu(robot):
    """A servo law far from the model's moves a swinging femur off the prediction as much as a stance
    femur's load; the body's motion on /imu then tells the walk (the slowest simulated walks rock it
    0.033 rad/s RMS), and a body at rest, gyro noise and bias only, does not."""
    hidden = _walk_like(robot, stance_offset_ticks=-2)
    assert not _looks_like_walk(robot, hidden)
    assert _looks_like_walk(robot, _imu(hidden, 0.03))
    assert not _looks_like_walk(robot, _imu(hidden, 0.0))
    one_leg = replace(hidden, commands={j: s for j, s in hidden.commands.items() if j.leg == 1},
                      states={j: s for j, s in hidden.states.items() if j.leg == 1})
    assert not _looks_like_walk(robot, _imu(one_leg, 0.1))      # one leg moving is never a walk


def test_parse_windows():
    assert parse_windows(['12:20', '2.5:10']) == [(2.5, 10.0), (12.0, 20.0)]
    for bad in ('5', 'a:b', '3:2', '-1:2'):
        with pytest.raises(RecordingError, match='--time'):
            parse_windows([bad])
