"""Algorithm 1 logic on a kinematic bus with a flat virtual ground (no physics; the MuJoCo
contact tests live in test_sim_locomotion.py)."""
import numpy as np
import pytest
from fakes import KinematicGroundBus

from hexapod_locomotion.core.controller import GaitController
from hexapod_locomotion.core.detector import (
    STOP_CONTACT,
    STOP_THETA_FIN,
    DetectorConfig,
    DetectorError,
    SwingDownPhase,
    run_swing_down,
)
from hexapod_locomotion.core.gait import get_gait
from hexapod_locomotion.core.locomotion_params import LocomotionParams, VelocityCommand
from hexapod_model.description import LEGS, load_robot
from hexapod_model.kinematics import forward

RAISED = [0.9, -0.9]
FIN = [0.05, -0.75]


@pytest.fixture(scope='module')
def robot():
    return load_robot()


def _phase(robot, kind, legs=(1, 6, 3), t_des=0.5, t0=0.0):
    L = len(legs)
    return SwingDownPhase(robot, legs, [0.0] * L, [RAISED] * L, [FIN] * L, t_des, 0.001,
                          DetectorConfig(detector=kind), t_start_s=t0)


def test_reads_follow_the_algorithm1_schedule(robot):
    bus = KinematicGroundBus(robot, ground_z_m=None)
    ph = run_swing_down(bus, _phase(robot, 'adaptive'))
    femur_reads = [(t, j) for t, j in bus.reads]
    assert [j for _, j in femur_reads[:6]] == ['leg1_femur', 'leg6_femur', 'leg3_femur'] * 2
    assert [t for t, _ in femur_reads[:6]] == pytest.approx([0.0, 0.001, 0.002, 0.003, 0.004, 0.005])
    # without ground every leg runs to theta_fin and says so
    assert all(s.stop_reason == STOP_THETA_FIN for s in ph.state.values())
    assert len(bus.writes) == ph.n_interp


@pytest.mark.parametrize('kind', ['adaptive', 'fixed'])
def test_stops_at_contact_not_before(robot, kind):
    ground = -0.10
    bus = KinematicGroundBus(robot, ground_z_m=ground)
    ph = run_swing_down(bus, _phase(robot, kind))
    for leg, s in ph.state.items():
        assert s.stop_reason == STOP_CONTACT
        # the first read after which the goal foot went below the ground
        first_contact = next(r.stamp_s for r in s.history
                             if forward(robot, leg, [0.0, (r.theta_des_tick - 512) * robot.servo.rad_per_tick,
                                                      -0.9 + 0.15 * r.t_swing_s / 0.5])[2] < ground - 1e-4)
        assert s.stop_time_s >= first_contact


def test_fixed_threshold_stops_later_with_more_error(robot):
    res = {}
    for kind in ('adaptive', 'fixed'):
        bus = KinematicGroundBus(robot, ground_z_m=-0.10)
        ph = run_swing_down(bus, _phase(robot, kind))
        res[kind] = (np.mean([s.stop_time_s for s in ph.state.values()]),
                     np.mean([s.history[-1].err_tick for s in ph.state.values()]))
    assert res['fixed'][0] > res['adaptive'][0]
    assert res['fixed'][1] > 20 and res['fixed'][1] > 1.5 * res['adaptive'][1]


def test_premature_error_spike_needs_confirmation(robot):
    ph = _phase(robot, 'adaptive', legs=(1,))
    ph.goals(0)
    # a spike on the very first read, while the foot has not descended: suspect, not a stop
    r = ph.on_read(0, 1, RAISED[0] + 0.2, 0.0)
    assert r.premature_suspect and not r.stopped
    ph.goals(1)
    r = ph.on_read(1, 1, RAISED[0] - 0.001, 0.001)
    assert not r.stopped and ph.state[1].suspect_count == 0
    for k in range(2, 2 + ph.config.confirm_reads):
        ph.goals(k)
        r = ph.on_read(k, 1, RAISED[0] + 0.2, k * 0.001)
    assert r.stopped and r.stop_reason == STOP_CONTACT
    assert ph.state[1].premature_suspects == 1 + ph.config.confirm_reads


@pytest.mark.parametrize('approach_rate', [1.0, 0.5])
def test_dwell_at_theta_fin_finds_ground_just_above_it(robot, approach_rate):
    """Ground 1 mm above the foot at theta_fin: the blocked error builds too late for Algorithm 1, which
    stops at theta_fin (a missed contact); reading on for 20 steps at theta_fin finds the ground."""
    ground = forward(robot, 1, [0.0, *FIN])[2] + 0.001
    out = {}
    for dwell in (0, 20):
        bus = KinematicGroundBus(robot, ground_z_m=ground)
        ph = SwingDownPhase(robot, (1, 6, 3), [0.0] * 3, [RAISED] * 3, [FIN] * 3, 0.5, 0.001, DetectorConfig(),
                            approach_from=0.6, approach_rate=approach_rate, fin_dwell_steps=dwell)
        run_swing_down(bus, ph)
        out[dwell] = ph
    assert all(s.stop_reason == STOP_THETA_FIN and s.stop_step == out[0].n_interp - 1 for s in out[0].state.values())
    for s in out[20].state.values():
        assert s.stop_reason == STOP_CONTACT and out[20].n_interp - 1 < s.stop_step < out[20].n_interp + 20
    with pytest.raises(DetectorError, match='fin_dwell_steps'):
        SwingDownPhase(robot, (1,), [0.0], [RAISED], [FIN], 0.5, 0.001, DetectorConfig(), fin_dwell_steps=-1)
    with pytest.raises(DetectorError, match='approach_rate'):
        SwingDownPhase(robot, (1,), [0.0], [RAISED], [FIN], 0.5, 0.001, DetectorConfig(), approach_rate=1.5)


def test_dwell_margin_finds_ground_a_servo_tick_above_theta_fin(robot):
    """Ground 0.3 mm above the foot at theta_fin (about half a femur tick): in a 12-step dwell Eq. 17's
    3-tick margin lets the leg run out to theta_fin, the dwell's own 1-tick margin finds the ground. Before
    the dwell (and in Algorithm 1, which has none) the threshold is Eq. 17's, whatever the dwell's."""
    ground = forward(robot, 1, [0.0, *FIN])[2] + 0.0003
    out = {}
    for dwell_eps in (3.0, 1.0):
        bus = KinematicGroundBus(robot, ground_z_m=ground)
        ph = SwingDownPhase(robot, (1, 6, 3), [0.0] * 3, [RAISED] * 3, [FIN] * 3, 0.5, 0.001,
                            DetectorConfig(dwell_epsilon_tick=dwell_eps), approach_from=0.6, approach_rate=0.5,
                            fin_dwell_steps=12)
        run_swing_down(bus, ph)
        out[dwell_eps] = ph
    assert all(s.stop_reason == STOP_THETA_FIN for s in out[3.0].state.values())
    assert all(s.stop_reason == STOP_CONTACT and s.stop_step >= out[1.0].n_interp for s in out[1.0].state.values())
    for leg in (1, 6, 3):
        before = [r for r in out[1.0].state[leg].history if r.step < out[1.0].n_interp]
        assert all(r.threshold_tick == pytest.approx(r.err_est_tick + 3.0) for r in before)
        dwelling = [r for r in out[1.0].state[leg].history if r.step >= out[1.0].n_interp]
        assert dwelling and all(r.threshold_tick == pytest.approx(r.err_est_tick + 1.0) for r in dwelling)
    with pytest.raises(DetectorError, match='dwell_epsilon_tick'):
        DetectorConfig(dwell_epsilon_tick=-1.0)


def test_bad_detector_input(robot):
    with pytest.raises(DetectorError, match="detector: must be one of adaptive, fixed, got 'psychic'"):
        DetectorConfig(detector='psychic')
    ph = _phase(robot, 'fixed', legs=(2,))
    ph.goals(0)
    with pytest.raises(DetectorError, match='not finite'):
        ph.on_read(0, 2, float('nan'), 0.0)


def test_gait_cycle_on_kinematic_ground(robot):
    """Three feet stay down in tripod; missing ground is reported and the body stays level."""
    bus = KinematicGroundBus(robot, ground_z_m=-0.11)
    reports = []
    # rigid servos: no compliance for a landing preload to stand for (it would tilt the feet's plane)
    c = GaitController(robot, get_gait('tripod'), LocomotionParams(t_des_s=0.5, landing_preload=0.0),
                       on_phase=reports.append)
    c.startup(bus)
    for _ in range(4):
        c.step_phase(bus, VelocityCommand(0.05, 0.0, 0.0))
    assert all(o.stop_reason == STOP_CONTACT for r in reports for o in r.outcomes)
    assert all(abs(r.body_roll_pitch_rad[0]) < 0.02 and abs(r.body_roll_pitch_rad[1]) < 0.02 for r in reports)
    bus = KinematicGroundBus(robot, ground_z_m=-0.5)     # a hole: nothing to find
    c = GaitController(robot, get_gait('tripod'), LocomotionParams(t_des_s=0.5))
    c.startup(bus)
    rep = c.step_phase(bus)
    assert all(o.stop_reason == STOP_THETA_FIN for o in rep.outcomes)
    assert any('no ground found' in w for w in rep.warnings)


def test_a_leg_without_ground_is_not_leveled_on_but_the_body_keeps_its_place(robot):
    """Pentapod, leg 1's foothold over a hole (no ground down to theta_fin): the body's tilt and height
    come from the five feet on the ground (it stays level), its position from all six (Eq. 10's
    average), so it does not fall back towards the rear feet; leg 1 waits over the spot where it looked
    for ground, at the nominal ground's height, until it swings again. Rigid kinematic ground, no landing
    preload."""
    feet = {}
    for ground in (-0.11, {1: None, 2: -0.11, 3: -0.11, 4: -0.11, 5: -0.11, 6: -0.11}):
        bus = KinematicGroundBus(robot, ground_z_m=ground)
        c = GaitController(robot, get_gait('pentapod'), LocomotionParams(t_des_s=0.5, landing_preload=0.0))
        c.startup(bus)
        reports = [c.step_phase(bus, VelocityCommand(0.05, 0.0, 0.0)) for _ in range(3)]   # legs 3, 5, 1
        c.finish(bus)
        feet[isinstance(ground, dict)] = np.array([c.foot(leg) for leg in LEGS])
    assert [o.stop_reason for o in reports[2].outcomes] == [STOP_THETA_FIN]
    assert max(map(abs, reports[2].body_roll_pitch_rad)) < 0.01
    flat, hole = feet[False], feet[True]
    # the body where the same walk on flat ground put it (centred on the five feet: 4-5 cm back and aside)
    np.testing.assert_allclose(hole[:, :2].mean(axis=0), flat[:, :2].mean(axis=0), atol=1e-3)
    # the feet on the ground too, but for a slight turn (the yaw is fitted to the five)
    np.testing.assert_allclose(hole[1:], flat[1:], atol=0.01)
    # leg 1 over its foothold (theta_fin is straight below the swing's end, the contact on the leg's path
    # to it: 1-2 cm apart; the neutral pose is 6 cm back), at the ground's height (theta_fin: 3 cm below)
    np.testing.assert_allclose(hole[0], flat[0], atol=0.015)
    assert abs(hole[0, 2] - flat[0, 2]) < 2e-3


def test_overlapped_transfer_levels_while_the_next_group_swings(robot):
    """With overlap_transfer the leveling after a swing-down runs beside the next group's
    swing-up and swing-forward. Every phase after the first is shorter by t_level_s + t_swing_up_s +
    t_swing_forward_s - max(t_level_s, t_swing_up_s + t_swing_forward_s); the swing-downs and the
    leveled pose are those of the sequential cycle; finish() carries out the last leveling."""
    runs = {}
    for overlap in (False, True):
        bus = KinematicGroundBus(robot, ground_z_m=-0.11)
        reports = []
        p = LocomotionParams(t_des_s=0.5, landing_preload=0.0, overlap_transfer=overlap)
        c = GaitController(robot, get_gait('tripod'), p, on_phase=reports.append)
        c.startup(bus)
        for _ in range(4):     # a full stride per cycle in both (their cycles differ, so would 0.05 m/s)
            c.step_phase(bus, VelocityCommand(0.2, 0.0, 0.0))
        c.finish(bus)
        assert all(o.stop_reason == STOP_CONTACT for r in reports for o in r.outcomes)
        runs[overlap] = (p, reports, np.array([c.foot(leg) for leg in range(1, 7)]))
    p, seq, feet_seq = runs[False]
    _, ovl, feet_ovl = runs[True]
    for r in seq[1:]:
        assert r.t_swing_down_start_s - r.t_start_s == pytest.approx(0.1 + 0.2 + p.t_settle_s, abs=0.01)
        assert r.t_end_s - r.t_swing_down_end_s == pytest.approx(p.t_level_s, abs=0.01)
    for r in ovl[1:]:
        assert r.t_swing_down_start_s - r.t_start_s == pytest.approx(max(p.t_level_s, 0.1 + 0.2) + p.t_settle_s,
                                                                     abs=0.01)
        assert r.t_end_s - r.t_swing_down_end_s < 0.005          # the leveling is left to the next transfer
    for a, b in zip(seq, ovl):
        assert [o.stop_time_s for o in a.outcomes] == pytest.approx([o.stop_time_s for o in b.outcomes], abs=0.01)
    np.testing.assert_allclose(feet_ovl, feet_seq, atol=2e-3)    # finish() stands in the leveled pose
