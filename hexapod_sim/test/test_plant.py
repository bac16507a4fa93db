"""HexapodSim: firmware, bus timing, effects, sensors; the free swing matches the swing-down model."""
import math

import numpy as np
import pytest
import yaml

from hexapod_model.description import ALL_JOINTS, Effect, joint_name, load_robot
from hexapod_model.servo import firmware_torque_nm, quantize_tick, theta_to_tick, winding_loss_w
from hexapod_model.swing_model import interpolated_goals, predict_swing_down
from hexapod_sim.physics.mjcf import FOOT_RADIUS_M
from hexapod_sim.physics.plant import ERR_ANGLE_LIMIT, ERR_OVERHEATING, HexapodSim, PowerMeter, SimError

RAISED = [0.45, 0.1]     # femur, tibia at the end of swing-forward [rad] (as in the model's tests)
BELOW = [-0.15, -0.05]   # theta_fin below the (absent) ground


@pytest.fixture(scope='module')
def robot():
    return load_robot()


@pytest.fixture(scope='module')
def stand(robot):
    return HexapodSim(robot, fixed_base=True)


def _tick(theta, robot):
    return theta_to_tick(theta, robot.servo)


# ----------------------------------------------------------------------------- the swing-down model
@pytest.mark.parametrize('t_des', [0.5, 1.0, 2.0])
def test_free_swing_follows_the_swing_down_model(robot, stand, t_des):
    """Algorithm 1 on the stand (body fixed, no ground), legs 1, 6, 3 as in the paper's tripod:
    the femur error read over the bus agrees with CalcModel within 1 tick RMS."""
    legs = [1, 6, 3]
    init, fin = np.array([RAISED] * 3), np.array([BELOW] * 3)
    pred = predict_swing_down(robot, legs, init, fin, t_des, stand.t_com_s)
    start = {joint_name(leg, r): v for leg in legs for r, v in zip(('femur', 'tibia'), RAISED)}
    stand.reset(joint_angles=start)
    K = pred.theta_des_tick.shape[0]
    goals = np.rint(interpolated_goals(_tick(init, robot), _tick(fin, robot), t_des, pred.t_con_s, K))
    read = np.zeros((K, 3))
    t_read = np.zeros((K, 3))
    for k in range(K):                                   # Algorithm 1, lines 5-15
        stand.sync_write({joint_name(leg, r): float((goals[k, slot, i] - robot.servo.center_tick)
                                                    * robot.servo.rad_per_tick)
                          for slot, leg in enumerate(legs) for i, r in enumerate(('femur', 'tibia'))})
        for slot, leg in enumerate(legs):
            theta, t_read[k, slot] = stand.read_position(joint_name(leg, 'femur'))
            read[k, slot] = _tick(theta, robot)
    np.testing.assert_allclose(t_read, pred.t_read_s, atol=1e-12)     # same read instants
    np.testing.assert_array_equal(goals[:, :, 0], pred.theta_des_tick)  # same goal sequence
    err_sim = pred.direction * (pred.theta_des_tick - read)
    rms = np.sqrt(np.mean((err_sim - pred.err_est_tick) ** 2, axis=0))
    assert np.all(rms < 1.0), f't_des={t_des}: femur error RMS difference per leg {rms} ticks'
    assert np.max(err_sim[:, 0]) >= 1.0            # a real lag was measured, not a trivial match
    assert not stand.warnings()


# ----------------------------------------------------------------------------- scenes
SCENES = [('flat', (0.0, 0.0)), ('blocks', (0.8, 0.0)), ('stairs', (0.62, 0.0)), ('rough', (0.6, 0.3)),
          ('mockup', (1.35, 0.0))]


@pytest.mark.parametrize('terrain,start', SCENES)
def test_every_scene_steps_5s_with_random_goals_without_warnings(robot, terrain, start):
    sim = HexapodSim(robot, terrain=terrain, seed=2, start_xy_m=start)
    rng = np.random.default_rng(11)
    lo = np.array([robot.joint_limits(j)[0] for j in ALL_JOINTS])
    hi = np.array([robot.joint_limits(j)[1] for j in ALL_JOINTS])
    while sim.now() < 5.0:
        sim.sync_write(dict(zip(ALL_JOINTS, rng.uniform(lo, hi))))
        sim.step(0.05)
    assert sim.warnings() == {}
    assert np.all(np.isfinite(sim.data.qpos)) and np.all(np.isfinite(sim.data.qvel))
    assert np.abs(sim.data.qvel).max() < 100.0


def test_fixed_base_steps_with_random_goals_without_warnings(robot):
    sim = HexapodSim(robot, fixed_base=True)
    rng = np.random.default_rng(12)
    while sim.now() < 3.0:
        sim.sync_write({j: rng.uniform(*robot.joint_limits(j)) for j in ALL_JOINTS})
        sim.step(0.05)
    assert sim.warnings() == {}
    assert sim.body_pose()[0][2] == pytest.approx(0.40)      # welded in the air


def test_stands_in_home_pose_on_flat_ground_without_sliding_or_sinking(robot):
    sim = HexapodSim(robot, terrain='flat')
    sim.step(0.5)                                    # the servos take the load (compliance sag)
    p0, _ = sim.body_pose()
    feet0 = sim.foot_positions()
    sim.step(3.0)
    p1, q1 = sim.body_pose()
    feet1 = sim.foot_positions()
    assert np.linalg.norm(p1[:2] - p0[:2]) < 2e-4                 # no sliding of the trunk
    assert abs(p1[2] - p0[2]) < 5e-4                              # no sinking (< 0.5 mm in 3 s)
    assert np.abs(feet1[:, :2] - feet0[:, :2]).max() < 5e-4       # feet do not creep
    assert math.degrees(2 * math.acos(min(1.0, abs(q1[0])))) < 0.1   # level
    c = sim.foot_contacts()
    assert c.in_contact.all()
    assert c.force_world_n[:, 2].sum() == pytest.approx(robot.total_mass_kg * robot.gravity_mps2, rel=0.01)
    penetration = FOOT_RADIUS_M - feet1[:, 2]
    assert np.all(penetration < 1e-3)
    # the trunk sags below the spawn height only by the servos' compliance: a few ticks of femur error
    sag = sim.scene.spawn_height_m - p1[2]
    assert 0 < sag < 0.01


def test_runs_are_deterministic(robot):
    def run():
        sim = HexapodSim(robot, terrain='blocks', start_xy_m=(0.8, 0.0))
        rng = np.random.default_rng(4)
        reads = []
        for _ in range(20):
            sim.sync_write({j: rng.uniform(*robot.joint_limits(j)) for j in ALL_JOINTS})
            reads += [sim.read_position(j)[0] for j in ALL_JOINTS]
            sim.foot_contacts()                         # truth queries must not change the run
        return np.array(reads), sim.data.qpos.copy(), sim.battery().energy_j
    a, b = run(), run()
    assert np.array_equal(a[0], b[0]) and np.array_equal(a[1], b[1]) and a[2] == b[2]


# ----------------------------------------------------------------------------- bus
def test_reads_are_sequential_and_cost_t_com(robot):
    for t_com in (0.001, 0.016):
        sim = HexapodSim(robot, fixed_base=True, t_com_s=t_com)
        t_write = sim.sync_write({'leg1_femur': 0.2})
        assert t_write == 0.0 and sim.now() == 0.0            # a write costs no bus time by default
        stamps = [sim.read_position(j)[1] for j in ('leg1_femur', 'leg6_femur', 'leg3_femur')]
        np.testing.assert_allclose(stamps, [0.0, t_com, 2 * t_com], atol=1e-12)
        assert sim.now() == pytest.approx(3 * t_com)
        sim.wait_until(0.0)                                   # in the past: no-op
        assert sim.now() == pytest.approx(3 * t_com)
        sim.wait_until(0.1)
        assert sim.now() == pytest.approx(0.1)
    timed = HexapodSim(robot, fixed_base=True, t_write_s=0.002)
    assert timed.sync_write({'leg1_femur': 0.1}) == 0.0 and timed.now() == pytest.approx(0.002)


def test_read_reports_the_quantised_tick_at_the_start_of_the_read(stand, robot):
    stand.reset()
    stand.sync_write({'leg2_femur': 0.8})                     # a fast move
    stand.step(0.03)
    for _ in range(20):
        true = stand.true_joint_angles()[ALL_JOINTS.index('leg2_femur')]
        theta, t = stand.read_position('leg2_femur')
        tick = _tick(theta, robot)
        assert tick == pytest.approx(round(tick), abs=1e-9)            # an integer tick
        assert tick == quantize_tick(_tick(true, robot), robot.servo)   # of the position at the sample
        assert stand.now() - t == pytest.approx(stand.t_com_s)
    assert abs(_tick(stand.true_joint_angles()[ALL_JOINTS.index('leg2_femur')], robot) - tick) > 1  # it moved


def test_goal_takes_effect_at_the_first_firmware_tick_at_or_after_the_write(robot):
    sim = HexapodSim(robot, fixed_base=True, timestep_s=0.0005)
    i = ALL_JOINTS.index('leg1_coxa')
    sim.step(0.0105)                        # t = 10.5 ms, between firmware ticks
    before = sim.applied_torque_nm()[i]
    sim.sync_write({'leg1_coxa': 0.3})
    sim.step(0.0005)                        # t = 11 ms: the tick at 11 ms has not run yet
    assert sim.applied_torque_nm()[i] == before
    sim.step(0.0005)                        # the firmware ran at 11 ms with the new goal
    assert sim.applied_torque_nm()[i] == pytest.approx(robot.servo.stall_torque_nm)   # 59 ticks away: saturated
    sim.sync_write({'leg1_coxa': -0.3})     # written exactly at the 11.5 ms step ...
    sim.step(0.0005)                        # ... acts from the 12 ms tick on (not before: held torque)
    assert sim.applied_torque_nm()[i] == pytest.approx(robot.servo.stall_torque_nm)
    sim.step(0.0005)
    assert sim.applied_torque_nm()[i] == pytest.approx(-robot.servo.stall_torque_nm)


def test_torque_is_the_firmware_law_on_integer_ticks(robot):
    r = robot.with_effects([Effect('torque_saturation', ('leg2_femur',), {'tau_max_nm': 0.4}),
                            Effect('compliance_deadband', ('leg3_tibia',), {'margin_ticks': 2.0})])
    sim = HexapodSim(r, fixed_base=True)
    rng = np.random.default_rng(3)
    s = r.servo
    tmax = np.array([0.4 if j == 'leg2_femur' else s.stall_torque_nm for j in ALL_JOINTS])
    margin = np.array([2.0 if j == 'leg3_tibia' else 0.0 for j in ALL_JOINTS])
    for _ in range(30):
        sim.sync_write({j: rng.uniform(*r.joint_limits(j)) for j in ALL_JOINTS})
        sim.step(rng.integers(1, 40) * 0.001)
        present = quantize_tick(_tick(sim.true_joint_angles(), r), s)   # what the firmware reads now
        sim.step(0.001)                                                 # one firmware tick
        want = firmware_torque_nm(sim.goal_ticks(), present, s.gain_nm_per_tick, tmax, margin, s.punch_nm)
        np.testing.assert_array_equal(sim.applied_torque_nm(), want)
    assert abs(sim.applied_torque_nm()[ALL_JOINTS.index('leg2_femur')]) <= 0.4


def test_compiled_quantiser_equals_quantize_tick(robot):
    from hexapod_sim.physics.firmware import quantize_array
    x = np.concatenate([np.random.default_rng(0).uniform(-5, 1030, 5000), np.arange(-3, 1027) + 0.5,
                        [-0.5, 0.5, 1022.5, 1023.5, 511.5, 512.5, -0.49, 1023.49]])
    np.testing.assert_array_equal(quantize_array(x, float(robot.servo.max_tick)), quantize_tick(x, robot.servo))


def test_compiled_loop_equals_a_plain_numpy_reference(robot):
    """The compiled firmware+physics loop is bit for bit the obvious implementation: at every 1 ms
    tick quantize_tick -> firmware_torque_nm -> ctrl, then mujoco.mj_step from Python."""
    import mujoco
    a = HexapodSim(robot, terrain='blocks', start_xy_m=(0.8, 0.0))
    b = HexapodSim(robot, terrain='blocks', start_xy_m=(0.8, 0.0))
    s = robot.servo
    rng = np.random.default_rng(8)
    qadr = [b.model.joint(j).qposadr[0] for j in ALL_JOINTS]
    for _ in range(20):
        goals = {j: rng.uniform(*robot.joint_limits(j)) for j in ALL_JOINTS}
        a.sync_write(goals)
        b.sync_write(goals)
        a.step(0.025)
        for _k in range(25):
            present = quantize_tick(theta_to_tick(b.data.qpos[qadr], s), s)
            b.data.ctrl[:] = firmware_torque_nm(b.goal_ticks(), present, s.gain_nm_per_tick, s.stall_torque_nm,
                                                0.0, s.punch_nm)
            mujoco.mj_step(b.model, b.data)
    assert np.array_equal(a.data.qpos, b.data.qpos) and np.array_equal(a.data.qvel, b.data.qvel)


def test_bus_direction_and_offset(robot, tmp_path):
    ov = tmp_path / 'mount.yaml'
    ov.write_text(yaml.safe_dump({'bus': {'joints': {'leg1_femur': {'direction': -1, 'offset_ticks': 7}}}}))
    r = load_robot(overlays=[ov])
    sim = HexapodSim(r, fixed_base=True)
    sim.sync_write({'leg1_femur': 0.3})
    sim.step(0.5)
    theta, _ = sim.read_position('leg1_femur')
    true = sim.true_joint_angles()[ALL_JOINTS.index('leg1_femur')]
    assert abs(theta - true) <= 0.5 * r.servo.rad_per_tick + 1e-12     # reported in the joint's frame
    assert abs(true - 0.3) < 10 * r.servo.rad_per_tick                 # it went where it was told
    raw = sim.goal_ticks()[ALL_JOINTS.index('leg1_femur')]
    assert raw == round(r.servo.center_tick - 0.3 / r.servo.rad_per_tick + 7)   # the servo's own tick


def test_bad_bus_input_is_named(robot, stand):
    with pytest.raises(SimError, match="unknown joint 'leg7_femur'"):
        stand.sync_write({'leg7_femur': 0.0})
    with pytest.raises(SimError, match='leg1_tibia: goal must be finite'):
        stand.sync_write({'leg1_femur': 0.0, 'leg1_tibia': float('nan')})
    with pytest.raises(SimError, match='unknown joint'):
        stand.read_position('femur')
    with pytest.raises(SimError, match='mapping'):
        stand.sync_write([0.1, 0.2])
    with pytest.raises(SimError, match='t_com_s'):
        HexapodSim(robot, fixed_base=True, t_com_s=0.0015)
    with pytest.raises(SimError, match='t_com_s'):
        HexapodSim(robot, fixed_base=True, t_com_s=-1.0)


def test_goal_outside_the_limits_is_clamped_and_flagged(robot, stand):
    stand.reset()
    lo, hi = robot.joint_limits('leg1_tibia')
    stand.sync_write({'leg1_tibia': hi + 0.5})
    i = ALL_JOINTS.index('leg1_tibia')
    assert stand.goal_ticks()[i] == quantize_tick(_tick(hi, robot), robot.servo)
    assert stand.servo_state().error_bits[i] & ERR_ANGLE_LIMIT
    stand.sync_write({'leg1_tibia': 0.0})
    assert not stand.servo_state().error_bits[i] & ERR_ANGLE_LIMIT


# ----------------------------------------------------------------------------- effects
def test_static_friction_holds_a_leg_that_coulomb_friction_lets_fall(robot):
    def drift(r):
        sim = HexapodSim(r, fixed_base=True)
        sim.reset(joint_angles={'leg1_femur': 0.3, 'leg1_tibia': 0.2})
        sim.set_torque_enabled(False, ['leg1_femur', 'leg1_tibia'])    # gravity ~0.1 N m on the femur
        q0 = sim.true_joint_angles()[1]
        sim.step(1.0)
        return (sim.true_joint_angles()[1] - q0) / r.servo.rad_per_tick
    assert drift(robot) < -20                                      # 0.06 N m Coulomb friction: it falls
    sticky = robot.with_effects([Effect('static_friction', ('leg1_femur',), {'tau_s_nm': 0.3})])
    assert abs(drift(sticky)) < 0.05                               # 0.3 N m break-away: it stays


def test_readout_delay_reports_an_older_position(robot):
    r = robot.with_effects([Effect('readout_delay', ('leg2_femur',), {'delay_s': 0.004})])
    sim = HexapodSim(r, fixed_base=True)
    i = ALL_JOINTS.index('leg2_femur')
    sim.sync_write({'leg2_femur': 1.0})
    truth = {}
    for _ in range(40):
        truth[round(sim.now() * 1000)] = sim.true_joint_angles()[i]
        sim.step(0.001)
    for _ in range(10):
        truth[round(sim.now() * 1000)] = sim.true_joint_angles()[i]
        theta, t = sim.read_position('leg2_femur')
        old = truth[round((t - 0.004) * 1000)]
        assert _tick(theta, r) == quantize_tick(_tick(old, r), r.servo)
        assert _tick(theta, r) != quantize_tick(_tick(truth[round(t * 1000)], r), r.servo)   # moving: differs


def test_backlash_is_real_play_between_motor_and_link(robot, tmp_path):
    """Gravity off, femur torque off: a 0.05 N m push on the link (below the motor's 0.06 N m
    friction) turns it across the play until the gear teeth meet; without backlash nothing moves."""
    ov = tmp_path / 'g0.yaml'
    ov.write_text('gravity_mps2: 0.0\n')
    w = 0.05
    r = load_robot(overlays=[ov]).with_effects([Effect('backlash', ('leg1_femur',), {'width_rad': w})])
    sim = HexapodSim(r, fixed_base=True)
    sim.set_torque_enabled(False, ['leg1_femur'])
    play = sim.model.joint('leg1_femur_backlash')
    motor = sim.model.joint('leg1_femur')
    motor0 = sim.data.qpos[motor.qposadr[0]]
    ends, outputs = [], []
    for push in (0.05, -0.05):
        sim.data.qfrc_applied[play.dofadr[0]] = push
        sim.step(0.5)
        ends.append(sim.data.qpos[play.qposadr[0]])
        outputs.append(sim.true_joint_angles()[1])
        # the potentiometer is on the output: the reported angle includes the play
        theta, _ = sim.read_position('leg1_femur')
        assert abs(theta - outputs[-1]) <= 0.5 * r.servo.rad_per_tick + 1e-12
    assert ends[0] == pytest.approx(w / 2, rel=0.02) and ends[1] == pytest.approx(-w / 2, rel=0.02)
    # the tooth impact carries the motor a little (momentum), far less than the play itself
    assert abs(sim.data.qpos[motor.qposadr[0]] - motor0) < 0.2 * w
    assert outputs[0] - outputs[1] > 0.9 * w
    assert not sim.warnings()
    nominal = HexapodSim(load_robot(overlays=[ov]), fixed_base=True)
    nominal.set_torque_enabled(False, ['leg1_femur'])
    nominal.data.qfrc_applied[nominal.model.joint('leg1_femur').dofadr[0]] = 0.05
    q0 = nominal.true_joint_angles()[1]
    nominal.step(0.5)
    assert abs(nominal.true_joint_angles()[1] - q0) < 1e-4


def test_backlash_everywhere_is_stable(robot):
    """Violent random goals with 30 mrad of play in every joint: no warnings, and the gear teeth
    (a stiff joint limit) are never pushed more than 15 mrad into each other."""
    r = robot.with_effects([Effect('backlash', ALL_JOINTS, {'width_rad': 0.03})])
    sim = HexapodSim(r, terrain='blocks', start_xy_m=(0.8, 0.0))
    rng = np.random.default_rng(1)
    qadr = [sim.model.joint(j + '_backlash').qposadr[0] for j in ALL_JOINTS]
    worst = 0.0
    while sim.now() < 2.0:
        sim.sync_write({j: rng.uniform(*r.joint_limits(j)) for j in ALL_JOINTS})
        for _ in range(10):
            sim.step(0.005)
            worst = max(worst, float(np.abs(sim.data.qpos[qadr]).max()))
    assert sim.warnings() == {}
    assert 0.015 <= worst < 0.015 + 0.015


def test_payload_adds_its_gravity_torque_to_the_femur_error(robot):
    def femur_error(r):
        sim = HexapodSim(r, fixed_base=True)
        sim.reset(joint_angles={'leg1_femur': 0.0, 'leg1_tibia': 0.0})
        sim.step(1.0)
        theta, _ = sim.read_position('leg1_femur')
        return sim.goal_ticks()[1] - _tick(theta, r)
    payload = 0.2
    heavy = robot.with_effects([Effect('mass_error', ('leg1_tibia',), {'payload_kg': payload})])
    psi2 = robot.dh['femur'].theta_off_rad
    psi23 = psi2 + robot.dh['tibia'].theta_off_rad
    # hand derivation: extra torque m g (a2 cos psi2 + a3 cos psi23), error = torque / gain
    extra = payload * robot.gravity_mps2 * (robot.dh['femur'].a_m * math.cos(psi2)
                                            + robot.dh['tibia'].a_m * math.cos(psi23))
    expected = extra / robot.servo.gain_nm_per_tick
    got = femur_error(heavy) - femur_error(robot)
    # +-2 ticks: integer ticks and the Coulomb friction band (0.06 N m = 1.3 ticks) on each run
    assert got == pytest.approx(expected, abs=2.0) and expected > 5


# ----------------------------------------------------------------------------- sensors
def test_imu_at_rest_and_its_400hz_stamps(stand, robot):
    stand.reset()
    stand.pop_imu_samples()
    stand.step(0.1)
    samples = stand.pop_imu_samples()
    np.testing.assert_allclose([s.t_s for s in samples], np.arange(40) * 0.0025, atol=1e-12)
    for s in samples:
        np.testing.assert_allclose(s.quat_wxyz, [1, 0, 0, 0], atol=1e-9)
        np.testing.assert_allclose(s.accel, [0, 0, robot.gravity_mps2], atol=1e-6)
        np.testing.assert_allclose(s.gyro, 0, atol=1e-9)


def test_imu_equals_mujocos_own_sensors(robot):
    """The IMU is computed from the free joint (cheaper); it equals MuJoCo's framequat,
    accelerometer and gyro at the trunk site for the same states."""
    import mujoco
    sim = HexapodSim(robot, terrain='flat', timestep_s=0.0005)    # 2.5 ms = 5 steps: exact samples
    sim.emergency_stop()                                          # the robot collapses: it moves
    sensors = ('<sensor><framequat objtype="site" objname="imu"/><accelerometer site="imu"/>'
               '<gyro site="imu"/></sensor>\n  <keyframe>')
    m2 = mujoco.MjModel.from_xml_string(sim.scene.xml.replace('<keyframe>', sensors))
    d2 = mujoco.MjData(m2)
    want = {}
    for k in range(120):
        d2.qpos[:], d2.qvel[:], d2.ctrl[:] = sim.data.qpos, sim.data.qvel, 0.0
        d2.qacc_warmstart[:] = sim.data.qacc_warmstart
        mujoco.mj_forward(m2, d2)
        want[k] = d2.sensordata[:10].copy()
        sim.step(0.0005)
    got = sim.pop_imu_samples()
    assert len(got) == 24
    for smp in got:
        w = want[round(smp.t_s / 0.0005)]
        np.testing.assert_allclose(smp.quat_wxyz, w[:4], atol=1e-9)
        np.testing.assert_allclose(smp.accel, w[4:7], atol=1e-6)
        np.testing.assert_allclose(smp.gyro, w[7:10], atol=1e-9)
    assert max(abs(smp.accel[2] - robot.gravity_mps2) for smp in got) > 0.5   # it really moved


def test_imu_interpolates_between_physics_steps(robot):
    """At 1 ms physics steps the 2.5 ms samples are interpolated; a 0.5 ms run samples them exactly."""
    coarse = HexapodSim(robot, terrain='flat')
    fine = HexapodSim(robot, terrain='flat', timestep_s=0.0005)
    for sim in (coarse, fine):
        sim.emergency_stop()                           # the robot collapses: the trunk moves
        sim.step(0.2)
    a, b = coarse.pop_imu_samples(), fine.pop_imu_samples()
    assert [s.t_s for s in a] == pytest.approx([s.t_s for s in b])
    qa = np.array([s.quat_wxyz for s in a])
    qb = np.array([s.quat_wxyz for s in b])
    np.testing.assert_allclose(np.linalg.norm(qa, axis=1), 1.0, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(qb, axis=1), 1.0, atol=1e-12)
    za = np.array([s.accel[2] for s in a])
    zb = np.array([s.accel[2] for s in b])
    assert np.median(np.abs(za - zb)) < 0.5            # the same signal (different step sizes)


def test_battery_idle_and_holding_power(robot):
    sim = HexapodSim(robot, fixed_base=True)
    sim.emergency_stop()
    sim.step(2.0)
    b = sim.battery()
    assert b.power_w == pytest.approx(robot.electronics_idle_power_w)
    assert b.energy_j == pytest.approx(robot.electronics_idle_power_w * 2.0)
    assert b.current_a * b.voltage_v == pytest.approx(b.power_w)
    held = HexapodSim(robot, fixed_base=True)          # legs held against gravity, at rest
    held.reset(joint_angles={'leg1_femur': 0.4, 'leg1_tibia': 1.2, 'leg2_femur': 0.3, 'leg2_tibia': 1.0})
    held.step(2.0)
    tau = held.applied_torque_nm()
    assert np.count_nonzero(tau) >= 2
    want = robot.electronics_idle_power_w + float(np.sum(winding_loss_w(tau, 0.0, robot.servo)))
    assert held.battery().power_w == pytest.approx(want, abs=1e-3)


def test_power_meter_samples_average_over_their_period(robot):
    """/power samples (sim node and demo recording): each is the mean power since the previous one,
    so the mean of the samples over a stretch is the energy drawn over it / its length, whatever the
    instantaneous power did in between (a leg swinging here)."""
    sim = HexapodSim(robot, fixed_base=True)
    meter = PowerMeter(sim)
    e0, samples = sim.battery().energy_j, []
    for k in range(40):
        sim.sync_write({'leg1_femur': 0.5 * math.sin(k / 4), 'leg1_tibia': 1.0})
        sim.step(0.05)
        samples.append(meter.sample())
    b = sim.battery()
    assert np.mean([s.power_w for s in samples]) == pytest.approx((b.energy_j - e0) / 2.0, rel=1e-9)
    assert all(s.current_a * s.voltage_v == pytest.approx(s.power_w) for s in samples)
    assert np.std([s.power_w for s in samples]) > 0.1          # the swinging leg did change the power


def test_temperature_follows_the_first_order_thermal_model(robot):
    sim = HexapodSim(robot, fixed_base=True, ambient_c=22.0, initial_temperature_c=37.0)
    sim.emergency_stop()                               # no winding loss: pure cooling
    sim.step(3.0)
    s = robot.servo
    want = 22.0 + 15.0 * math.exp(-3.0 / s.thermal_time_constant_s)
    np.testing.assert_allclose(sim.temperatures_c(), want, rtol=0, atol=1e-9)


def test_overheating_servo_shuts_down(robot):
    """A femur pushed against its end stop by a hand while the servo pulls at stall torque heats up
    at (T_inf - T)/tau with T_inf = 22 C + R_th I^2 R; above 70 C it switches its torque off."""
    sim = HexapodSim(robot, fixed_base=True, initial_temperature_c=69.8)
    i = ALL_JOINTS.index('leg1_femur')
    sim.sync_write({'leg1_femur': robot.joint_limits('leg1_femur')[1]})
    sim.data.qfrc_applied[sim.model.joint('leg1_femur').dofadr[0]] = -4.0
    s = robot.servo
    t_inf = 22.0 + s.thermal_resistance_k_per_w * float(winding_loss_w(s.stall_torque_nm, 0.0, s))
    assert t_inf > 100
    sim.step(3.0)
    st = sim.servo_state()
    assert not st.torque_enabled[i]
    assert st.error_bits[i] & ERR_OVERHEATING or st.temperature_c[i] < s.shutdown_temperature_c
    others = np.arange(len(ALL_JOINTS)) != i
    assert st.torque_enabled[others].all() and not np.any(st.error_bits[others] & ERR_OVERHEATING)
    assert sim.applied_torque_nm()[i] == 0.0
    sim.data.qfrc_applied[:] = 0.0
    sim.step(10.0)                                        # it cools below the limit but stays off
    st = sim.servo_state()
    assert st.temperature_c[i] < s.shutdown_temperature_c and not st.error_bits[i] & ERR_OVERHEATING
    assert not st.torque_enabled[i]
    sim.set_torque_enabled(True, ['leg1_femur'])          # the operator re-enables it
    assert sim.servo_state().torque_enabled[i]


def test_emergency_stop_drops_the_robot_and_reset_restores(robot):
    sim = HexapodSim(robot, terrain='flat')
    sim.step(0.5)
    z0 = sim.body_pose()[0][2]
    sim.emergency_stop()
    sim.step(1.0)
    assert np.all(sim.applied_torque_nm() == 0.0) and not sim.torque_enabled.any()
    assert sim.body_pose()[0][2] < z0 - 0.01          # joint friction slows the collapse
    sim.reset()
    assert sim.now() == 0.0 and sim.torque_enabled.all()
    assert sim.body_pose()[0][2] == pytest.approx(sim.scene.spawn_height_m)
    np.testing.assert_allclose(sim.temperatures_c(), 37.0)


def test_a_goal_latency_makes_written_goals_act_that_many_firmware_ticks_later(robot):
    """The servo-law effect goal_latency: the firmware takes a written goal only ``delay_s`` after the
    first tick at or after the write (and a non-finite goal is still refused at the write)."""
    r = robot.with_effects([Effect('goal_latency', ALL_JOINTS, {'delay_s': 0.002})])
    late, now = HexapodSim(r, fixed_base=True), HexapodSim(robot, fixed_base=True)
    goal = {'leg1_femur': 0.4}
    for sim in (late, now):
        sim.step(0.01)
        sim.sync_write(goal)
    i = ALL_JOINTS.index('leg1_femur')
    g0 = late.goal_ticks()[i]
    assert now.goal_ticks()[i] != g0                      # acts at the write's own tick
    late.step(0.001)
    assert late.goal_ticks()[i] == g0                     # one tick later: not yet
    late.step(0.001)
    assert late.goal_ticks()[i] == now.goal_ticks()[i]    # two ticks later: the goal acts
    with pytest.raises(SimError):
        late.sync_write({'leg1_femur': float('nan')})
