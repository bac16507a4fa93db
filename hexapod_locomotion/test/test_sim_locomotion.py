"""Locomotion on the MuJoCo robot: Algorithm 1 against simulation truth, and walking the terrains.

Ground truth (foot contacts, femur torque, body pose) is read from the simulator for evaluation
only; the controller sees nothing but servo reads.
"""
import math
from concurrent.futures import ProcessPoolExecutor

import numpy as np
import pytest

from hexapod_locomotion.core.controller import GaitController
from hexapod_locomotion.core.detector import STOP_CONTACT, STOP_THETA_FIN, DetectorConfig, SwingDownPhase
from hexapod_locomotion.core.gait import get_gait
from hexapod_locomotion.core.locomotion_params import LocomotionParams, VelocityCommand
from hexapod_locomotion.trials.trial_runner import ProbeBus, TrialConfig, _detection_events, run_trial
from hexapod_model.description import load_robot
from hexapod_model.kinematics import stance_feet
from hexapod_sim.physics.mjcf import FOOT_RADIUS_M
from hexapod_sim.physics.plant import HexapodSim
from hexapod_sim.physics.terrain import Box, Terrain

BLOCK_TOP_M = 0.035


def _block_under_leg1(robot):
    """A 10 x 10 cm wooden block, 3.5 cm high, where leg 1 will put its foot (stride half ahead)."""
    foot = stance_feet(robot)[0]
    x, y = foot[0] + 0.03, foot[1]
    return Terrain('block_under_leg1', 0, boxes=(Box('block', (x, y, BLOCK_TOP_M - 0.05), (0.05, 0.05, 0.05)),))


def _one_phase(robot, kind, approach_rate=1.0, t_des=1.0):
    sim = HexapodSim(robot, terrain=_block_under_leg1(robot))
    probe = ProbeBus(sim)
    det = DetectorConfig(detector=kind)
    swing = []
    c = GaitController(robot, get_gait('tripod'), LocomotionParams(t_des_s=t_des, approach_rate=approach_rate), det,
                       t_com_s=sim.t_com_s, on_read=probe.record_detection, on_swing_start=swing.append)
    c.startup(probe)
    rep = c.step_phase(probe, VelocityCommand(0.05, 0.0, 0.0))      # legs 1, 6, 3 swing
    return {e.leg: e for e in _detection_events(robot, probe, swing[0], det)}, rep


@pytest.fixture(scope='module')
def robot():
    return load_robot()


@pytest.fixture(scope='module')
def scripted(robot):
    return {kind: _one_phase(robot, kind) for kind in ('adaptive', 'fixed')}


def test_detector_stops_on_the_block_not_before(scripted):
    events, rep = scripted['adaptive']
    assert set(events) == {1, 6, 3}
    for leg, e in events.items():
        assert e.stop_reason == STOP_CONTACT, f'leg {leg}'
        assert math.isfinite(e.t_true_contact_s), f'leg {leg} never touched'
        assert e.t_stop_s >= e.t_true_contact_s, f'leg {leg} stopped before touching the ground'
        assert e.t_stop_s - e.t_true_contact_s < 0.06, f'leg {leg} detected {e.t_stop_s - e.t_true_contact_s:.3f} s late'
    # leg 1 lands on the 3.5 cm block, so it finds ground earlier in its swing than legs on the floor
    o = {x.leg: x for x in rep.outcomes}
    assert o[1].stop_time_s < min(o[6].stop_time_s, o[3].stop_time_s) - 0.05


def test_fixed_baseline_stops_late_with_higher_torque(scripted):
    ad, _ = scripted['adaptive']
    fx, _ = scripted['fixed']
    for leg in (1, 6, 3):
        assert fx[leg].t_stop_s - fx[leg].t_swing_start_s > ad[leg].t_stop_s - ad[leg].t_swing_start_s
    contact = [leg for leg in (1, 6, 3) if fx[leg].stop_reason == STOP_CONTACT]
    tq_fixed = np.mean([fx[leg].peak_femur_torque_nm for leg in (1, 6, 3)])
    tq_adapt = np.mean([ad[leg].peak_femur_torque_nm for leg in (1, 6, 3)])
    assert tq_fixed > 1.3 * tq_adapt, (tq_fixed, tq_adapt, contact)


@pytest.mark.parametrize('t_des', [0.5, 1.0])
def test_improved_touchdown_stops_before_the_body_rises(robot, t_des):
    """The approach goal profile (approach_rate 0.5) on the same scripted swing onto the block: every
    leg still stops on contact and not before it, the trunk rises less than with the paper's Eq. 15
    goals and at most 2 mm, and the legs that land in the slow part (6 and 3, on the floor; leg 1
    meets the 3.5 cm block before it) press with less torque."""
    paper, _ = _one_phase(robot, 'adaptive', 1.0, t_des)
    improved, rep = _one_phase(robot, 'adaptive', 0.5, t_des)
    for leg, e in improved.items():
        assert e.stop_reason == STOP_CONTACT, f'leg {leg}'
        assert e.t_true_contact_s <= e.t_stop_s < e.t_true_contact_s + 0.08, f'leg {leg}'
        assert math.isfinite(e.floor_periods) and e.floor_periods > 0, f'leg {leg}'
    rise, rise_paper = improved[1].body_rise_m, paper[1].body_rise_m
    assert rise <= 0.002 and rise < 0.8 * rise_paper, (rise, rise_paper)
    for leg in (6, 3):
        assert improved[leg].peak_femur_torque_nm < 0.85 * paper[leg].peak_femur_torque_nm, leg
    # the price: the floor legs' swing-down takes longer
    o = {x.leg: x for x in rep.outcomes}
    assert o[6].stop_time_s > paper[6].t_stop_s - paper[6].t_swing_start_s


@pytest.mark.parametrize('t_des', [0.5, 1.0, 2.0])
@pytest.mark.parametrize('cell', ['adaptive', 'improved'])
@pytest.mark.parametrize('gait', ['tripod', 'pentapod'])
def test_no_premature_stop_in_free_swing(robot, t_des, cell, gait):
    """On a stand (no ground) every swing-down must run to theta_fin, with the paper's Eq. 15 goals
    and with the improved touchdown (the experiments' cell: approach profile, dwell at theta_fin and
    the dwell's smaller Eq. 17 margin)."""
    from hexapod_locomotion.trials.experiments import variant_fields
    from hexapod_locomotion.trials.trial_runner import TrialConfig, detector_config, locomotion_params
    cfg = TrialConfig(gait=gait, t_des_s=t_des, **variant_fields(cell))
    sim = HexapodSim(robot, terrain='flat', fixed_base=True)
    c = GaitController(robot, get_gait(gait), locomotion_params(cfg), detector_config(cfg), t_com_s=sim.t_com_s)
    c.startup(sim)
    legs = len(get_gait(gait).swing_legs(0))
    for _ in range(6 // legs):
        rep = c.step_phase(sim, VelocityCommand(0.05, 0.0, 0.0))
        assert [o.stop_reason for o in rep.outcomes] == [STOP_THETA_FIN] * legs
        assert all(o.premature_suspects == 0 for o in rep.outcomes)


class _LateController:
    """A ServoBus around the sim for a controller that is late now and then, as a computer in real time
    is: the bus idles ``late_s`` before the first write of a swing-down (the model prediction is
    computed after the phase's start time was taken) and before every ``every``-th write after it."""

    def __init__(self, sim, late_s=0.005, every=4):
        self.sim, self.t_com_s, self.late_s, self.every, self.writes = sim, sim.t_com_s, late_s, every, 0

    def now(self):
        return self.sim.now()

    def sync_write(self, goals):
        if self.writes % self.every == 0:
            self.sim.wait_until(self.sim.now() + self.late_s)
        self.writes += 1
        return self.sim.sync_write(goals)

    def wait_until(self, t):
        self.sim.wait_until(t)

    def read_position(self, joint):
        return self.sim.read_position(joint)


class _StallBeforeRead(_LateController):
    """A controller that pauses ``stall_s`` between a write and the next read after every
    ``every``-th write (the host paused, a read was retried): the driver route did, when a garbage
    collection held the bus emulator for 65-70 ms."""

    def __init__(self, sim, stall_s=0.07, every=40):
        super().__init__(sim, late_s=0.0, every=1)
        self.stall_s, self.stall_every, self.pending = stall_s, every, False

    def sync_write(self, goals):
        self.pending = self.writes % self.stall_every == self.stall_every - 1
        return super().sync_write(goals)

    def read_position(self, joint):
        if self.pending:
            self.sim.wait_until(self.sim.now() + self.stall_s)
            self.pending = False
        return self.sim.read_position(joint)


def _stalling_bus(sim, where, stall_s):
    if where == 'before a read':
        return _StallBeforeRead(sim, stall_s=stall_s)
    return _LateController(sim, late_s=stall_s, every=40)       # before a write


@pytest.mark.parametrize('where', ['before a read', 'before a write'])
@pytest.mark.parametrize('stall_s', [0.03, 0.07, 0.15])
def test_a_stall_of_the_host_does_not_stop_a_free_swing(robot, where, stall_s):
    """On a stand, a pause of 30-150 ms every 40 writes (between a write and its reads, or before a
    write) still lets every swing-down run to theta_fin: the hold is replayed into the model, whose
    leg then comes to rest at the held goal and lags again from zero, as the real one does. Without
    the replay, 30 ms and more stopped the free legs (10-20 ms did not)."""
    sim = HexapodSim(robot, terrain='flat', fixed_base=True)
    c = GaitController(robot, get_gait('tripod'), LocomotionParams(t_des_s=0.5), DetectorConfig(detector='adaptive'),
                       t_com_s=sim.t_com_s)
    c.startup(sim)
    bus = _stalling_bus(sim, where, stall_s)
    retimed = []
    c.on_swing_start = lambda phase: retimed.append(phase.retimed_steps)
    reasons = [o.stop_reason for _ in range(2) for o in c.step_phase(bus, VelocityCommand(0.05, 0.0, 0.0)).outcomes]
    assert sum(len(r) for r in retimed) >= 2                    # stalls happened inside the swing-downs
    assert reasons == [STOP_THETA_FIN] * 6


@pytest.mark.parametrize('where', ['before a read', 'before a write'])
def test_a_stall_of_the_host_still_finds_the_block(robot, where):
    """Onto a block under leg 1, with a 70 ms pause every 40 writes: leg 1 still stops on contact,
    not before its foot touched the block and within 15 control periods of it (15 of its reads: a
    pause that falls after the touch delays the reads, and no detector stops a leg it does not read)."""
    sim = HexapodSim(robot, terrain=_block_under_leg1(robot))
    swing, touch = [], []
    c = GaitController(robot, get_gait('tripod'), LocomotionParams(t_des_s=0.5), DetectorConfig(detector='adaptive'),
                       t_com_s=sim.t_com_s, on_swing_start=swing.append,
                       on_read=lambda r: touch.append((r.stamp_s, bool(sim.foot_contacts().in_contact[0])))
                       if r.leg == 1 else None)
    c.startup(sim)
    bus = _stalling_bus(sim, where, 0.07)
    out = {o.leg: o for o in c.step_phase(bus, VelocityCommand(0.05, 0.0, 0.0)).outcomes}
    assert swing[0].retimed_steps                              # a stall fell into this swing-down
    assert out[1].stop_reason == STOP_CONTACT
    stop = swing[0].state[1].stop_time_s
    first = next(t for t, touching in touch if touching)
    assert first <= stop
    assert len([t for t, _ in touch if first < t <= stop + 1e-9]) <= 15


class _PhaseOnStartTimes(SwingDownPhase):
    """Algorithm 1 as it was before the model was read relative to each step's write: at the read's
    time since the phase began, whatever the writes did."""

    def wrote(self, k, t_s):
        pass


@pytest.mark.parametrize('anchored', [True, False])
def test_late_steps_do_not_stop_a_free_swing(robot, anchored, monkeypatch):
    """On a stand (no ground), a controller whose writes come late (5 ms before the first and every
    fourth step) still runs every swing-down to theta_fin: the model is read at each read's time
    after its own step's write. Read at the time since the phase began instead, the prediction runs
    ahead of the late goals and the free legs stop in the air - what the real-time robot did."""
    import hexapod_locomotion.core.controller as controller
    if not anchored:
        monkeypatch.setattr(controller, 'SwingDownPhase', _PhaseOnStartTimes)
    sim = HexapodSim(robot, terrain='flat', fixed_base=True)
    c = GaitController(robot, get_gait('tripod'), LocomotionParams(t_des_s=0.5), DetectorConfig(detector='adaptive'),
                       t_com_s=sim.t_com_s)
    c.startup(sim)
    bus = _LateController(sim)
    reasons = [o.stop_reason for _ in range(2) for o in c.step_phase(bus, VelocityCommand(0.05, 0.0, 0.0)).outcomes]
    if anchored:
        assert reasons == [STOP_THETA_FIN] * 6
    else:                      # the old reading: the test above would catch it
        assert STOP_CONTACT in reasons


def test_replay_with_the_recorded_writes_makes_the_live_decisions(robot):
    """``analyse`` replays a swing-down from its recorded reads and writes (/joint_commands): with a
    late controller, the replay stops each leg at the same step as the live run."""
    from hexapod_locomotion.core.detector import replay_swing_down, run_swing_down
    sim = HexapodSim(robot, terrain=_block_under_leg1(robot))
    c = GaitController(robot, get_gait('tripod'), LocomotionParams(), DetectorConfig(detector='adaptive'),
                       t_com_s=sim.t_com_s)
    c.startup(sim)
    legs = (1, 6, 3)
    init = [[sim.read_position(f'leg{leg}_{r}')[0] for r in ('femur', 'tibia')] for leg in legs]
    fin = [[init[i][0] - 0.6, init[i][1] + 0.1] for i in range(3)]
    coxa = [c.leg_angles(leg)[0] for leg in legs]

    def phase():
        return SwingDownPhase(robot, legs, coxa, init, fin, 0.5, sim.t_com_s, DetectorConfig(detector='adaptive'),
                              t_start_s=t0)
    t0 = sim.now()
    bus = _LateController(sim, late_s=0.004, every=3)
    reads, writes = [], []
    write, read = bus.sync_write, bus.read_position
    bus.sync_write = lambda g: writes.append(write(g)) or writes[-1]
    bus.read_position = lambda j: reads.append((int(j[3]), *read(j))) or reads[-1][1:]
    live = run_swing_down(bus, phase())
    assert any(s.stop_reason == STOP_CONTACT for s in live.state.values())
    again = replay_swing_down(phase(), reads, writes=writes)
    assert {leg: (s.stop_step, s.stop_reason) for leg, s in again.state.items()} == \
        {leg: (s.stop_step, s.stop_reason) for leg, s in live.state.items()}


class _SupportProbe:
    """A ServoBus around the sim that counts the feet down (MuJoCo contact, or a foot within 1 mm of
    the ground: soft contact flickers for a millisecond at near-zero force) at every bus read,
    i.e. every 1 ms of walking."""

    def __init__(self, sim):
        self.sim, self.t_com_s, self.down = sim, sim.t_com_s, []

    def now(self):
        return self.sim.now()

    def sync_write(self, goals):
        return self.sim.sync_write(goals)

    def wait_until(self, t):
        self.sim.wait_until(t)

    def read_position(self, joint):
        out = self.sim.read_position(joint)
        feet = self.sim.foot_positions()
        clearance = feet[:, 2] - FOOT_RADIUS_M - self.sim.scene.terrain.height_at(feet[:, 0], feet[:, 1])
        down = self.sim.foot_contacts().in_contact | (clearance < 1e-3)
        self.down.append((out[1], int(down.sum())))
        return out


@pytest.mark.parametrize('gait, feet', [('tripod', 3), ('tetrapod', 4), ('pentapod', 5)])
def test_support_feet_stay_down_at_every_tick_on_flat_ground(robot, gait, feet):
    """In MuJoCo, not only in the gait table: 3 / 4 / 5 feet on the ground while walking, at every
    read but for brief rocking. Needs the landing preload: a leg held at its contact pose takes no
    load after leveling and lifts off when the next group swings (without it 4506 of 6500 reads of a
    tetrapod and 2304 of a pentapod have a support foot up). With the AX-12A's punch in the servo law
    the pentapod's body rocks once when a middle leg lifts: a front foot rises 1.4 mm for 31 reads."""
    sim = HexapodSim(robot, terrain='flat')
    probe = _SupportProbe(sim)
    c = GaitController(robot, get_gait(gait), LocomotionParams(t_des_s=0.5), DetectorConfig(), t_com_s=sim.t_com_s)
    c.startup(probe)
    t_walk = sim.now()
    for _ in range(9):
        c.step_phase(probe, VelocityCommand(0.05, 0.0, 0.0))
    counts = np.array([n for t, n in probe.down if t > t_walk])
    assert len(counts) > 5000
    assert np.count_nonzero(counts < feet) <= 0.01 * len(counts), (np.bincount(counts),
                                                                  np.flatnonzero(counts < feet)[:5])
    assert counts.min() >= feet - 1


def _walk(gait):
    r = run_trial(TrialConfig(gait=gait, detector='adaptive', t_des_s=0.5, terrain='blocks', duration_s=150,
                              course_end_m=1.05, probe_period_s=0.1))
    return gait, r


def test_walks_one_metre_over_blocks_with_every_gait():
    with ProcessPoolExecutor(max_workers=2) as ex:
        results = dict(ex.map(_walk, ['pentapod', 'tripod', 'tetrapod']))
    for gait, r in results.items():
        assert not r.fell, (gait, r.warnings)
        assert r.reached_course_end and r.distance_m >= 1.0, (gait, r.distance_m)
        tilt = [max(abs(s['var_roll']), abs(s['var_pitch'])) for s in r.stability]
        assert max(tilt) < 0.01, gait          # variance of roll/pitch within a swing-down: bounded


@pytest.mark.parametrize('vx, wz', [(0.0, 0.15), (0.04, -0.15)])
def test_turns_in_place_and_on_the_move(robot, vx, wz):
    sim = HexapodSim(robot, terrain='flat')
    c = GaitController(robot, get_gait('tripod'), LocomotionParams(t_des_s=0.5), t_com_s=sim.t_com_s)
    c.startup(sim)
    p0, _ = sim.body_pose()
    for _ in range(6):
        c.step_phase(sim, VelocityCommand(vx, 0.0, wz))
    p1, q = sim.body_pose()
    yaw = 2 * math.atan2(q[3], q[0])
    assert yaw * np.sign(wz) > 0.1, yaw                     # turned the commanded way
    moved = np.linalg.norm(p1[:2] - p0[:2])
    if vx == 0.0:
        assert moved < 0.05, moved                          # in place
    else:
        assert moved > 0.05, moved


# the legs still move at the swing-down start. A 0.1 s swing-forward is beyond the model even started in
# motion since a leg without ground no longer takes the body back with it (on the stand every leg is one,
# and the strides are now full): 2 of 12 middle legs stopped at the swing-down's second step at t_des 0.5 s
# (0 with 0.12 s, where started at rest 3-4 of 12 still stop; the default cycle's free swings: none)
_HURRIED = dict(t_settle_s=0.0, t_swing_up_s=0.05, t_swing_forward_s=0.12, t_level_s=0.17)


@pytest.mark.parametrize('t_des', [0.5, 1.0])
def test_a_model_started_in_motion_lets_a_hurried_leg_swing_free(robot, t_des):
    """No settle after a fast swing-forward: the legs still move when the swing-down starts. Started at
    rest (the paper), the model predicts less lag than the moving leg has and Algorithm 1 stops legs in
    the air; started in the leg's motion (start_in_motion), every leg swings free to theta_fin."""
    def stops(start_in_motion):
        sim = HexapodSim(robot, terrain='flat', fixed_base=True)
        c = GaitController(robot, get_gait('tripod'),
                           LocomotionParams(t_des_s=t_des, start_in_motion=start_in_motion, **_HURRIED),
                           DetectorConfig(detector='adaptive'), t_com_s=sim.t_com_s)
        c.startup(sim)
        return [o.stop_reason for _ in range(4) for o in c.step_phase(sim, VelocityCommand(0.05, 0.0, 0.0)).outcomes]
    assert stops(True) == [STOP_THETA_FIN] * 12
    assert STOP_CONTACT in stops(False)


def test_a_model_started_in_motion_still_stops_on_the_block(robot):
    sim = HexapodSim(robot, terrain=_block_under_leg1(robot))
    c = GaitController(robot, get_gait('tripod'), LocomotionParams(t_des_s=0.5, start_in_motion=True, **_HURRIED),
                       DetectorConfig(detector='adaptive'), t_com_s=sim.t_com_s)
    c.startup(sim)
    rep = c.step_phase(sim, VelocityCommand(0.05, 0.0, 0.0))      # legs 1, 6, 3 swing
    o = {x.leg: x for x in rep.outcomes}
    assert all(x.stop_reason == STOP_CONTACT for x in o.values())
    # leg 1 on the block: it stops higher, i.e. earlier, than the legs that reach the floor
    assert o[1].stop_time_s < min(o[6].stop_time_s, o[3].stop_time_s)
