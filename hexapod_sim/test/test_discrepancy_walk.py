"""The discrepancy tool on a clean walk recorded by the sim (bags/tripod_blocks_adaptive): gait phases
found from the commands agree with the controller's own telemetry, and the nominal replay of the
swings matches every analysed joint to within 0.5 tick RMS on held-out reads, with no effect reported."""
from pathlib import Path

import numpy as np
import pytest

from hexapod_model.description import Effect, load_robot
from hexapod_model.imu import ImuSeries
from hexapod_model.joints import Joint
from hexapod_sim.bagio import BagReader
from hexapod_sim.discrepancy.analysis import analyse
from hexapod_sim.discrepancy.recording import load_recording
from hexapod_sim.discrepancy.report import to_json
from hexapod_sim.discrepancy.segments import gait_phases, swing_segments
from hexapod_sim.discrepancy.simulate import Replay

BAG = Path(__file__).resolve().parents[2] / 'bags' / 'tripod_blocks_adaptive'


@pytest.fixture(scope='module')
def robot():
    return load_robot()


@pytest.fixture(scope='module')
def rec(robot):
    if not BAG.exists():
        pytest.skip(f'{BAG} not in this checkout')
    return load_recording(BAG, robot)


def _telemetry(rec):
    """Swing-down starts per leg and the stamp of each leg's stopping read, from the controller's topics."""
    t0 = rec.t0_ns * 1e-9
    starts, stops = {}, {}
    for topic, _, _, msg in BagReader(str(BAG)).messages(topics=['/swing_down', '/ground_detection']):
        t = msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9 - t0
        if topic == '/swing_down':
            for leg in msg.legs:
                starts.setdefault(int(leg), []).append(t)
        elif msg.stopped and msg.stop_reason != 0:
            stops.setdefault(int(msg.leg), []).append(t)
    return starts, stops


def test_gait_phases_match_the_controller_telemetry(rec):
    phases = gait_phases(rec, range(1, 7))
    starts, stops = _telemetry(rec)
    for leg in range(1, 7):
        sw = phases[leg].swings
        assert len(sw) == len(starts[leg]), leg
        for s, t_sd in zip(sw, starts[leg]):
            assert s.t_up < s.t_forward < s.t_down < s.t_stop
            assert abs(s.t_down - t_sd) < 0.005                     # first swing-down write
            later = [t for t in stops[leg] if t >= t_sd]
            if not later:                                          # cut off by the end of the recording
                assert s is sw[-1] and s.t_stop >= rec.duration_s - 1.0, (leg, s)
                continue
            assert -0.005 < s.t_stop - min(later) < 0.02             # the last goal step at the stop
            assert s.t_forward - s.t_up == pytest.approx(0.10, abs=0.012)   # the demo's t_swing_up_s (gaits.yaml)


def test_clean_walk_replays_at_the_rounding_floor_and_no_effect_is_reported(rec, robot):
    a = analyse(rec, robot, workers=1)
    assert a.mode == 'walk'
    assert a.effects == []
    assert len(a.joints) == 18
    for j, v in a.joints.items():
        assert v.n_heldout >= 10, j
        assert v.heldout_rmse_ticks_before < 0.5, (j, v)
    doc = to_json(a, str(BAG))
    assert set(doc['phases']['leg1_femur']) >= {'swing_forward', 'swing_down'}
    assert all(m.get('phase') in ('swing_up', 'swing_forward', 'swing_down') for m in doc['mismatches'])
    # the rounding floor itself: what a perfect model leaves is about 0.29 ticks
    assert np.median([v.heldout_rmse_ticks_before for v in a.joints.values()]) < 0.36


def test_walk_is_judged_on_alternate_swings_and_cannot_show_is_computed(rec, robot):
    """Fit and held-out reads come from alternate swings of each leg (every leg of the walk has both),
    and each joint listed under "cannot show" is one where the typical effect changes the prediction
    of its fitting or held-out reads by too little for the drop an accepted effect needs over tick
    rounding, or on too few held-out reads (and vice versa)."""
    from hexapod_sim.discrepancy.effects import BY_NAME
    from hexapod_sim.discrepancy.predict import Predictor, can_confirm, prediction_change
    a = analyse(rec, robot, workers=1)
    for j in a.replay.joints:
        seg = a.replay.reads[j].segment
        assert set(seg[a.split.fit[j]]) <= set(range(0, 99, 2)), j
        assert set(seg[a.split.hold[j]]) <= set(range(1, 99, 2)), j
        assert a.split.fit[j].any() and a.split.hold[j].any(), j
    pred = Predictor(a.replay, robot, workers=1)
    p0 = pred.predict([], a.replay.joints)
    femur1 = Joint(1, 'femur')
    assert 'static_friction' in a.blind and femur1 not in a.blind.get('coulomb_friction', ())
    for name, joint in (('static_friction', a.blind['static_friction'][0]), ('coulomb_friction', femur1)):
        c = BY_NAME[name]
        change = prediction_change(pred, a.split, p0, c.make((joint,), c.typical))
        assert (not can_confirm(change, a.min_drop_ticks, a.min_gain_ticks2)) == (joint in a.blind.get(name, ())), \
            (name, joint, change)


def test_a_walk_of_the_fast_overlapped_cycle_is_named_as_such():
    """The report says when a walk's gait cycle moves the body under the swinging legs (other legs
    leveling during a swing) or lifts legs faster than the replay is measured for, and points to the
    calibration walk; a walk in sequence with unhurried swing-ups gets no such note."""
    from types import SimpleNamespace

    from hexapod_sim.discrepancy.segments import LegPhases, Swing, body_motion_share, walk_cycle_notes

    def walk(up_s, overlapped):
        phases, segs = {}, {}
        for leg in (1, 2):
            t0 = 0.0 if leg == 1 else 2.0
            sw = Swing(t0, t0 + up_s, t0 + up_s + 0.25, t0 + 1.0)
            # the other leg levels the body: right after this leg's swing-down (in sequence) or
            # while this leg swings up and forward (overlapped)
            other0 = 2.0 - t0
            lev = (other0, other0 + 0.3) if overlapped else (other0 + 1.0, other0 + 1.3)
            phases[leg] = LegPhases((sw,), (lev,))
            segs[leg] = [(t0 + 0.08, t0 + 0.9)]
        return phases, segs

    dt = 0.001
    for up_s, overlapped, expect in ((0.15, False, ()), (0.15, True, ('body moved',)),
                                     (0.1, False, ('swing-ups of 100 ms',)),
                                     (0.1, True, ('body moved', 'swing-ups of 100 ms'))):
        phases, segs = walk(up_s, overlapped)
        share = body_motion_share(phases, segs)
        assert (share > 0.2) == overlapped and (share == 0.0) == (not overlapped), share
        replay = SimpleNamespace(dt=dt, correction=None,
                                 segments={leg: [(round(a / dt), round(b / dt)) for a, b in v] for leg, v in segs.items()})
        notes = walk_cycle_notes(phases, replay)
        for word in expect:
            assert any(word in n for n in notes), (up_s, overlapped, notes)
        assert bool(notes) == bool(expect), notes
        assert not expect or 'calibration_walk.yaml' in notes[-1]


@pytest.fixture(scope='module')
def overlapped_walk(tmp_path_factory):
    """A clean 10 s tripod walk over the blocks with the controller's default (overlapped, fast) cycle."""
    locomotion = pytest.importorskip('hexapod_locomotion.trials.trial_runner')
    import contextlib
    import io
    bag = tmp_path_factory.mktemp('walk') / 'overlapped'
    cfg = locomotion.TrialConfig(gait='tripod', terrain='blocks', duration_s=10.0, course_end_m=3.0, record=str(bag),
                                 start_x_m=0.45)
    assert cfg.overlap_transfer             # the default cycle
    with contextlib.redirect_stdout(io.StringIO()):
        locomotion.run_trial(cfg)
    return bag


def test_the_body_motion_from_imu_brings_an_overlapped_walk_to_the_rounding_floor(overlapped_walk, robot):
    """The overlapped cycle moves the body under the swinging legs. With the bag's /imu the swings are
    replayed with that motion and a clean walk matches within 0.5 tick with no effect; the same reads
    without /imu leave more on some joint, and the report says why and what to record instead."""
    from dataclasses import replace

    rec = load_recording(overlapped_walk, robot)
    assert isinstance(rec.imu, ImuSeries) and rec.imu.accel.shape == rec.imu.gyro.shape == (len(rec.imu), 3)
    a = analyse(rec, robot, workers=1)
    assert a.mode == 'walk' and a.effects == []
    assert a.replay.correction is not None
    assert any('/imu' in n for n in a.notes)
    worst = max(v.heldout_rmse_ticks_before for v in a.joints.values())
    assert worst < 0.5, {j: v.heldout_rmse_ticks_before for j, v in a.joints.items()}
    b = analyse(replace(rec, imu=None), robot, workers=1)
    assert b.replay.correction is None
    worst_b = max(v.heldout_rmse_ticks_before for v in b.joints.values())
    assert worst_b > worst + 0.1, (worst, worst_b)
    assert any('body moved under the swinging legs' in n for n in b.notes)
    assert any('calibration_walk.yaml' in n for n in b.notes)


def test_a_welded_replay_with_gravity_minus_acceleration_is_a_moving_body():
    """What body_motion rests on: legs on a welded trunk under gravity g - a move as they do on a trunk
    accelerating by a under gravity g (the sim's free base, lifted off the ground)."""
    from hexapod_sim.discrepancy.body_motion import gravity_per_period
    from hexapod_sim.physics.plant import HexapodSim, SimError

    imu = ImuSeries(np.array([0.0, 1.0]), np.array([[1.0, 0.0, 9.81], [3.0, 0.0, 9.81]]), np.zeros((2, 3)))
    g = gravity_per_period(imu, 3, 0.5)
    assert np.allclose(g, [[-1.0, 0.0, -9.81], [-2.0, 0.0, -9.81], [-3.0, 0.0, -9.81]])
    sim = HexapodSim(fixed_base=True, imu_rate_hz=0.0)
    sim.reset()
    with pytest.raises(SimError, match='gravity'):
        sim.set_gravity([0.0, float('nan'), -9.81])
    with pytest.raises(SimError, match='leg9_coxa'):
        sim.set_joint_state({'leg9_coxa': 0.0}, {})
    q = sim.data.qpos[sim.joint_position_index('leg1_coxa')]
    sim.set_joint_state({'leg1_coxa': q + 0.1}, {'leg1_coxa': 0.5})
    assert sim.data.qpos[sim.joint_position_index('leg1_coxa')] == pytest.approx(q + 0.1)
    # a sideways effective gravity (the trunk accelerating sideways) pushes a coxa off its goal; plain
    # gravity, which a coxa does not feel, leaves it where it holds
    sim.set_joint_state({'leg1_coxa': q}, {'leg1_coxa': 0.0})
    sim.step(0.3)
    still = sim.data.qpos[sim.joint_position_index('leg1_coxa')]
    sim.set_gravity([0.0, 30.0, -9.81])
    sim.step(0.3)
    assert abs(sim.data.qpos[sim.joint_position_index('leg1_coxa')] - still) > 0.01


def test_an_imu_on_another_clock_is_not_used_and_said_so():
    from hexapod_sim.discrepancy.recording import screen_imu

    t = np.arange(0.0, 10.0, 0.0025)
    accel = np.column_stack([np.zeros_like(t), np.zeros_like(t), np.full_like(t, 9.81)])
    accel[0] = 0.0                                     # the sim's first sample: no specific force
    imu = ImuSeries(t + 100.0, accel, np.zeros((len(t), 3)))
    ok, why = screen_imu(imu, 100.0, 10.0)
    assert why == () and len(ok) == len(t) - 1 and ok.t_s[0] == pytest.approx(0.0025)
    bad, why = screen_imu(imu, 0.0, 10.0)              # /imu 100 s after the reads
    assert bad is None and len(why) == 1 and 'another clock' in why[0].detail and why[0].topic == 'imu'
    from hexapod_sim.discrepancy.glitches import summary_line
    assert '1 clock' in summary_line(why)


SERVO_LAW_BAG = BAG.parent / 'servo_law_walk'


def test_a_walk_of_a_plant_with_another_servo_law_names_the_servo_law_and_no_joint_effect(robot):
    """bags/servo_law_walk: a tripod calibration walk of a plant whose firmware has 32 more punch, 15 %
    more motor damping and goals one tick later (truth in servo_law_walk.truth.yaml). The tool names the
    servo law on the whole robot, no joint effect, and the fitted law brings every joint to tick rounding."""
    if not SERVO_LAW_BAG.exists():
        pytest.skip(f'{SERVO_LAW_BAG} not in this checkout')
    a = analyse(load_recording(SERVO_LAW_BAG, robot), robot, workers=1)
    found = {f.effect.effect: f for f in a.effects}
    assert {'punch', 'motor_damping'} <= set(found) <= {'punch', 'motor_damping', 'goal_latency'}, found
    assert all(len(f.effect.joints) == 18 for f in a.effects)
    assert found['punch'].effect.params['extra_punch_nm'] == pytest.approx(robot.servo.punch_nm, rel=0.25)
    assert found['motor_damping'].effect.params['ratio'] == pytest.approx(1.15, rel=0.03)
    assert max(v.heldout_rmse_ticks_before for v in a.joints.values()) > 1.5      # the model without the law
    assert max(v.heldout_rmse_ticks_after for v in a.joints.values()) < 0.5
    assert a.unexplained == []


def test_legs_that_all_swing_at_once_are_a_stand_routine_not_a_gait():
    from hexapod_sim.discrepancy.segments import _legs_swing_together
    together = {leg: [(1.0, 2.0), (5.0, 6.0)] for leg in range(1, 7)}
    tripod = {leg: ([(1.0, 2.0), (5.0, 6.0)] if leg in (1, 4, 5) else [(3.0, 4.0), (7.0, 8.0)]) for leg in range(1, 7)}
    assert _legs_swing_together(together)
    assert not _legs_swing_together(tripod)
    assert not _legs_swing_together({3: [(1.0, 2.0)]})             # one leg: nothing to compare


def test_an_unexplained_free_leg_mismatch_that_the_whole_walk_follows_is_not_reported():
    """The free-leg model leaves 0.94 ticks on a clean walk's femur (a swing that starts while the leg
    still sheds the body's weight); the MuJoCo replay of the whole walk follows that joint's swings to tick
    rounding, so nothing is claimed, whatever its touchdown shows (on the blocks a replay a fraction of a
    percent off takes a touchdown elsewhere). A joint whose swings the replay does not follow stays; so
    does everything when the replay went out of step early or judged a joint's swings on too few reads."""
    from hexapod_sim.discrepancy.findings import Unexplained
    from hexapod_sim.discrepancy.whole_walk_findings import whole_walk_agrees
    from hexapod_sim.discrepancy.whole_walk_search import PhaseRow, WholeWalk

    def walk(in_step_s, femur_swing=0.32, reads=200):
        rows = {Joint(2, 'femur'): {'swing_forward': PhaseRow(reads, 0.32, femur_swing),
                                    'touchdown': PhaseRow(200, 3.6, 3.6),
                                    'swing_down': PhaseRow(5, 3.0, 3.0)},           # too few reads to count
                Joint(5, 'tibia'): {'stance': PhaseRow(reads, 1.29, 1.29)}}      # no swing judged
        return WholeWalk(ground=None, in_step_until_s=in_step_s, nominal_in_step_until_s=in_step_s, phases=rows, runtime_s=1.0)

    femur = Unexplained((Joint(2, 'femur'),), 'start_from_rest', 0.94)
    tibia = Unexplained((Joint(5, 'tibia'),), 'gravity_load_high', 1.29)
    assert whole_walk_agrees([femur, tibia], walk(12.5), 12.5) == [tibia]
    assert whole_walk_agrees([femur, tibia], walk(12.5, femur_swing=0.8), 12.5) == [femur, tibia]
    assert whole_walk_agrees([femur, tibia], walk(5.0), 12.5) == [femur, tibia]       # out of step early
    assert whole_walk_agrees([femur], walk(12.5, reads=10), 12.5) == [femur]          # no swing judged
    assert whole_walk_agrees([femur], None, 12.5) == [femur]                          # no whole-walk replay


@pytest.mark.parametrize('truth_on, widened', [('leg', True), ('femur', False)])
def test_a_joint_effect_the_whole_walk_wants_on_its_whole_leg_is_put_there(tmp_path, robot, truth_on, widened):
    """A walking coxa and tibia are read a few times a swing, so the swings find a leg's viscous damping on
    its femur alone; the whole walk reads them in stance too, and puts the damping on the leg where the
    plant has it there, not where the plant has it on the femur only. A femur effect on a leg without it
    is not widened either."""
    bench = pytest.importorskip('hexapod_locomotion.bench.discrepancy_bench', reason='the locomotion package is not importable')
    from hexapod_model.description import Effect
    from hexapod_model.joints import LEG_JOINTS
    from hexapod_sim.discrepancy.whole_walk_findings import widen_to_legs
    from hexapod_sim.discrepancy.whole_walk_search import Replays, walk_ground

    def viscous(joints):
        return Effect('viscous_damping', tuple(joints), {'b_nms_per_rad': 0.13})

    truth = viscous(LEG_JOINTS[5] if truth_on == 'leg' else (Joint(5, 'femur'),))
    bag, _ = bench.record_walk(bench.Case('legwide', (truth,), walk=('pentapod', 'flat'), cycle='default'), tmp_path,
                               duration_s=8.0, seed=1)
    rec = load_recording(bag, robot)
    femur, elsewhere = viscous((Joint(5, 'femur'),)), viscous((Joint(2, 'femur'),))
    effects, moved = widen_to_legs(Replays(rec, robot, walk_ground(rec, None)[0]), [femur, elsewhere],
                                   [Joint.of(j) for j in rec.states])
    assert moved == ([(femur, viscous(LEG_JOINTS[5]))] if widened else [])
    assert effects == ([elsewhere, viscous(LEG_JOINTS[5])] if widened else [femur, elsewhere])


def test_the_swings_of_a_leg_rolled_out_together_are_each_swing_alone(rec, robot):
    # Replay.rollout_segments rolls a leg's swings out in one batch: bit for bit each swing's own rollout,
    # with an effect that takes the backlash kernel and one that takes the rigid one
    replay = Replay(robot, rec)
    replay = Replay(robot, rec, segments=swing_segments(rec, replay.legs, phases=gait_phases(rec, replay.legs)),
                    moving_start=True)
    model = robot.with_effects([Effect('backlash', ('leg2_tibia', 'leg5_coxa'), {'width_rad': 0.02}),
                                Effect('static_friction', ('leg1_femur',), {'tau_s_nm': 0.3})])
    for leg in (1, 2, 5):
        for which in ('ft', 'coxa'):
            together = replay.rollout_segments(model, leg, which)
            assert len(together) == len(replay.segments[leg]) > 3
            for i, (k0, q) in enumerate(together):
                k1, q1 = replay.rollout_leg(model, leg, i, which)
                assert k0 == k1 and np.array_equal(q, q1)
