"""Leg odometry (hexapod_locomotion.core.odometry) on hand-made foot sets whose motion is known."""
import math

import numpy as np
import pytest

from hexapod_locomotion.core.odometry import LegOdometry, OdometryConfig, OdometryError, planar_fit, plane_tilt
from hexapod_model.imu import ImuReading

# six feet on flat ground, world frame, the body 0.1 m above them at the start
WORLD = np.array([[0.2, 0.15, 0.0], [0.0, 0.2, 0.0], [-0.2, 0.15, 0.0],
                  [-0.2, -0.15, 0.0], [0.0, -0.2, 0.0], [0.2, -0.15, 0.0]])
ALL = np.ones(6, dtype=bool)


def rz(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def body_feet(world, x, y, z, yaw):
    """Feet in the body frame of a level body at (x, y, z, yaw)."""
    return (world - np.array([x, y, z])) @ rz(yaw)


def yaw_imu(yaw):
    """An IMU reading of a level body at heading ``yaw``."""
    return ImuReading(quat_wxyz=np.array([math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2)]))


def test_translation_of_the_body_is_the_opposite_motion_of_the_feet():
    odo = LegOdometry()
    e = odo.update(0.0, body_feet(WORLD, 0, 0, 0.1, 0), ALL)
    assert e.position == pytest.approx([0, 0, 0.1])        # height above the feet
    e = odo.update(1.0, body_feet(WORLD, 0.03, -0.01, 0.1, 0), ALL)
    assert e.position == pytest.approx([0.03, -0.01, 0.1], abs=1e-12)
    assert e.linear == pytest.approx([0.03, -0.01, 0.0])
    assert e.rpy == pytest.approx([0, 0, 0], abs=1e-12)
    assert e.feet_used == 6
    assert e.distance_m == pytest.approx(math.hypot(0.03, 0.01))


def test_turn_in_place_and_a_step_forward_in_the_new_heading():
    odo = LegOdometry()
    odo.update(0.0, body_feet(WORLD, 0, 0, 0.1, 0), ALL)
    e = odo.update(0.5, body_feet(WORLD, 0, 0, 0.1, 0.2), ALL)
    assert e.rpy[2] == pytest.approx(0.2)
    assert e.position[:2] == pytest.approx([0, 0], abs=1e-12)
    assert e.angular[2] == pytest.approx(0.4)
    # 2 cm forward along the new heading: (0.02 cos 0.2, 0.02 sin 0.2) in odom
    e = odo.update(1.0, body_feet(WORLD, 0.02 * math.cos(0.2), 0.02 * math.sin(0.2), 0.1, 0.2), ALL)
    assert e.position[:2] == pytest.approx([0.02 * math.cos(0.2), 0.02 * math.sin(0.2)], abs=1e-12)
    assert e.linear[:2] == pytest.approx([0.04, 0.0], abs=1e-12)


def test_only_feet_in_contact_at_both_updates_count():
    odo = LegOdometry()
    contact = np.array([True, False, True, False, True, False])   # a tripod on the ground
    odo.update(0.0, body_feet(WORLD, 0, 0, 0.1, 0), contact)
    moved = body_feet(WORLD, 0.02, 0, 0.1, 0)
    moved[[1, 3, 5]] += [0.05, 0.01, 0.0]                      # the swung feet landed elsewhere
    e = odo.update(1.0, moved, ALL)                             # they land: not in contact before, not used
    assert e.feet_used == 3
    assert e.position == pytest.approx([0.02, 0, 0.1], abs=1e-12)
    # next update: the landed feet (now where ``moved`` put them, fixed in the world) count too
    landed_world = moved @ rz(0).T + [0.02, 0, 0.1]
    e = odo.update(2.0, body_feet(landed_world, 0.05, 0.01, 0.1, 0), ALL)
    assert e.feet_used == 6
    assert e.position == pytest.approx([0.05, 0.01, 0.1], abs=1e-12)


def test_read_noise_does_not_add_up_within_a_stance():
    """The same feet, read with alternating 1 mm errors at every update, while the body stands still: the
    pose stays within the error of one read (no keyframe change), not a random walk."""
    odo = LegOdometry()
    rng = np.random.default_rng(0)
    for k in range(200):
        e = odo.update(0.01 * k, body_feet(WORLD, 0, 0, 0.1, 0) + rng.normal(0, 0.001, (6, 3)), ALL)
    assert np.hypot(*e.position[:2]) < 0.002
    assert e.distance_m > 0.02          # the path of the noisy estimate: the noise was there


def test_no_fit_with_fewer_than_two_feet_holds_the_pose():
    odo = LegOdometry()
    odo.update(0.0, body_feet(WORLD, 0, 0, 0.1, 0), np.array([1, 0, 0, 0, 0, 0], bool))
    e = odo.update(1.0, body_feet(WORLD, 0.05, 0, 0.1, 0), np.array([1, 0, 0, 0, 0, 0], bool))
    assert e.feet_used == 0
    assert e.position[:2] == pytest.approx([0, 0])


def test_stepping_up_raises_the_odometry_height():
    odo = LegOdometry()
    odo.update(0.0, body_feet(WORLD, 0, 0, 0.1, 0), ALL)
    # the body rises 3 cm (stairs): feet 3 cm further below it
    e = odo.update(1.0, body_feet(WORLD, 0, 0, 0.13, 0), ALL)
    assert e.position[2] == pytest.approx(0.13)
    assert e.linear[2] == pytest.approx(0.03)


def test_imu_yaw_is_fused_by_the_variances():
    """Four feet on a square of half side 0.1 m: mean squared distance to their centre 0.02 m^2, so the
    legs' yaw increment has variance 2 sigma^2 / (n 0.02) = 2 * 9e-6 / 0.08 = 2.25e-4 rad^2 (no slip:
    the body does not translate); the IMU's over 1 s: (0.005 rad/s * 1 s)^2 = 2.5e-5 rad^2. Weights:
    legs 2.5e-5 / 2.5e-4 = 0.1, IMU 0.9."""
    square = np.array([[0.1, 0.1, 0], [-0.1, 0.1, 0], [-0.1, -0.1, 0], [0.1, -0.1, 0], [0, 0, 0], [0, 0, 0]])
    contact = np.array([1, 1, 1, 1, 0, 0], bool)
    cfg = OdometryConfig(foot_sigma_m=0.003, gyro_sigma_rad_s=0.005)
    odo = LegOdometry(cfg)
    odo.update(0.0, body_feet(square, 0, 0, 0.1, 0), contact, yaw_imu(0.0))
    e = odo.update(1.0, body_feet(square, 0, 0, 0.1, 0.10), contact, yaw_imu(0.12))
    assert e.rpy[2] == pytest.approx(0.1 * 0.10 + 0.9 * 0.12)
    assert e.pose_cov[5, 5] == pytest.approx(2.5e-5 * 2.25e-4 / 2.5e-4)


def test_legs_that_slipped_together_leave_the_yaw_to_the_imu():
    """The square of the test above, the legs' yaw 0.10 rad, the IMU's 0.20: 0.1 rad apart is 6.3 standard
    deviations (sqrt(2.25e-4 + 2.5e-5) = 0.0158 rad), beyond the 3 of slip_gate_sigma: the feet slipped
    together, the IMU's yaw alone counts (fused by the variances it would be 0.19)."""
    square = np.array([[0.1, 0.1, 0], [-0.1, 0.1, 0], [-0.1, -0.1, 0], [0.1, -0.1, 0], [0, 0, 0], [0, 0, 0]])
    contact = np.array([1, 1, 1, 1, 0, 0], bool)
    odo = LegOdometry(OdometryConfig(foot_sigma_m=0.003, gyro_sigma_rad_s=0.005, slip_gate_sigma=3.0))
    odo.update(0.0, body_feet(square, 0, 0, 0.1, 0), contact, yaw_imu(0.0))
    e = odo.update(1.0, body_feet(square, 0, 0, 0.1, 0.10), contact, yaw_imu(0.20))
    assert e.rpy[2] == pytest.approx(0.20)
    assert e.pose_cov[5, 5] == pytest.approx(2.5e-5)


def test_feet_that_twisted_together_turn_the_body_about_their_centre():
    """The square of feet centred 0.1 m ahead of the body; the body turns in place by 0.2 rad (the IMU's
    yaw) while the feet twist together by -0.1 rad about their centre (the legs see 0.3 rad apart: the
    slip gate leaves the yaw to the IMU). The feet's centre stood: the displacement under the IMU's yaw
    keeps the body where it is; under the legs' own yaw (0.3 rad) it would move 1 cm."""
    square = np.array([[0.2, 0.1, 0], [0.0, 0.1, 0], [0.0, -0.1, 0], [0.2, -0.1, 0], [0, 0, 0], [0, 0, 0]])
    contact = np.array([1, 1, 1, 1, 0, 0], bool)
    centre = np.array([0.1, 0.0, 0.0])
    twisted = (square - centre) @ rz(-0.1).T + centre
    odo = LegOdometry(OdometryConfig(foot_sigma_m=0.003, gyro_sigma_rad_s=0.005, slip_gate_sigma=3.0))
    odo.update(0.0, body_feet(square, 0, 0, 0.1, 0), contact, yaw_imu(0.0))
    e = odo.update(1.0, body_feet(twisted, 0, 0, 0.1, 0.2), contact, yaw_imu(0.2))
    assert e.rpy[2] == pytest.approx(0.2)
    assert e.position[:2] == pytest.approx([0, 0], abs=1e-12)


@pytest.mark.parametrize('with_imu', [True, False])
def test_a_foot_sliding_among_standing_feet_is_left_out(with_imu):
    """A tripod (legs 1, 3, 5) stands while the body walks 2 cm ahead; leg 1's foot slides 2 cm sideways
    meanwhile. Taken with the others it would put the body 7 mm off to the side (a third of the slide,
    and through the yaw without an IMU); its displacement is 2 cm from the feet's median, over
    slip_foot_gate_m, so it is left out: with the IMU's yaw (fused with the legs' 24 mrad, which the
    slide also turned, to 0.75 mrad) the body is within 0.2 mm of where it is; from the legs alone their
    yaw keeps the slide's turn, and the body is 3 mm off."""
    contact = np.array([1, 0, 1, 0, 1, 0], bool)
    slid = WORLD.copy()
    slid[0, 1] += 0.02
    odo = LegOdometry()
    odo.update(0.0, body_feet(WORLD, 0, 0, 0.1, 0), contact, yaw_imu(0.0) if with_imu else None)
    e = odo.update(1.0, body_feet(slid, 0.02, 0, 0.1, 0), contact, yaw_imu(0.0) if with_imu else None)
    assert e.position == pytest.approx([0.02, 0, 0.1], abs=2e-4 if with_imu else 4e-3)


def test_two_feet_that_disagree_are_both_kept():
    """With two feet there is no telling which one slid: both count (their mean, under the fused yaw)."""
    contact = np.array([1, 0, 0, 1, 0, 0], bool)
    slid = WORLD.copy()
    slid[0, 1] += 0.02
    odo = LegOdometry()
    odo.update(0.0, body_feet(WORLD, 0, 0, 0.1, 0), contact, yaw_imu(0.0))
    e = odo.update(1.0, body_feet(slid, 0.02, 0, 0.1, 0), contact, yaw_imu(0.0))
    assert e.position[:2] == pytest.approx([0.02, -0.01], abs=1e-4)


def test_gyro_rate_alone_gives_the_yaw_when_no_foot_set_fits():
    odo = LegOdometry()
    none = np.zeros(6, bool)
    odo.update(0.0, body_feet(WORLD, 0, 0, 0.1, 0), none)
    e = odo.update(0.5, body_feet(WORLD, 0, 0, 0.1, 0), none, ImuReading(gyro=np.array([0, 0, 0.3])))
    assert e.rpy[2] == pytest.approx(0.15)


def test_imu_orientation_gives_roll_and_pitch():
    odo = LegOdometry()
    from scipy.spatial.transform import Rotation
    x, y, z, w = Rotation.from_euler('ZYX', [0.0, 0.05, -0.02]).as_quat()
    e = odo.update(0.0, body_feet(WORLD, 0, 0, 0.1, 0), ALL, ImuReading(quat_wxyz=np.array([w, x, y, z])))
    assert e.rpy[:2] == pytest.approx([-0.02, 0.05])


def test_plane_tilt_of_a_pitched_body():
    """A body pitched nose-down by 0.1 rad over flat ground sees the feet at R^T (world - body)."""
    from scipy.spatial.transform import Rotation
    rot = Rotation.from_euler('ZYX', [0.0, 0.1, 0.0]).as_matrix()
    feet = (WORLD - [0, 0, 0.1]) @ rot
    assert plane_tilt(feet) == pytest.approx((0.0, 0.1))
    assert plane_tilt(WORLD[[0, 1]]) is None


def test_planar_fit_of_an_exact_rigid_motion():
    a = 0.3
    before = WORLD[:4]
    after = (before - [0.05, 0.02, 0]) @ rz(a)                # before = Rz(a) after + (0.05, 0.02)
    dyaw, d, res = planar_fit(before, after)
    assert dyaw == pytest.approx(a)
    assert d == pytest.approx([0.05, 0.02])
    assert res == pytest.approx(0.0, abs=1e-12)


def test_heading_uncertainty_becomes_lateral_uncertainty():
    """Walking along x with an uncertain heading (a tripod's stances: every landing starts a new keyframe):
    y's variance grows faster than x's (an error in yaw moves the robot sideways)."""
    odo = LegOdometry(OdometryConfig(foot_sigma_m=1e-4, yaw_slip_rad_per_m=0.5, slip_fraction=0.001))
    odo.update(0.0, body_feet(WORLD, 0, 0, 0.1, 0), ALL)
    tripods = [np.array([1, 0, 1, 0, 1, 0], bool), ALL, np.array([0, 1, 0, 1, 0, 1], bool), ALL]
    e = None
    for k in range(1, 51):
        e = odo.update(float(k), body_feet(WORLD, 0.02 * k, 0, 0.1, 0), tripods[k % 4])
    assert e.position[0] == pytest.approx(1.0)
    assert e.pose_cov[1, 1] > 2 * e.pose_cov[0, 0] > 0
    assert e.pose_cov[5, 5] > 0
    assert np.allclose(e.pose_cov, e.pose_cov.T)


@pytest.mark.parametrize('bad, match', [
    (lambda o: o.update(0.0, np.full((6, 3), np.nan), ALL), 'non-finite'),
    (lambda o: o.update(0.0, np.zeros((5, 3)), ALL), '6 feet'),
    (lambda o: o.update(math.nan, WORLD, ALL), 'time'),
    (lambda o: o.update(0.0, WORLD, ALL, ImuReading(quat_wxyz=np.zeros(4))), 'IMU orientation'),
    (lambda o: o.update(0.0, WORLD, ALL, ImuReading(gyro=np.array([0, 0, np.inf]))), 'angular velocity'),
])
def test_bad_input_is_named(bad, match):
    with pytest.raises(OdometryError, match=match):
        bad(LegOdometry())


def test_the_same_instant_rounded_differently_is_not_a_step_back():
    # the lock-stepped node gave 4.497 after 4.497000000000001 and stopped the walk
    odo = LegOdometry()
    odo.update(4.497000000000001, WORLD, ALL)
    odo.update(4.497, WORLD, ALL)
    assert odo.t_s == 4.497000000000001


def test_time_must_not_go_back():
    odo = LegOdometry()
    odo.update(1.0, WORLD, ALL)
    with pytest.raises(OdometryError, match='go back'):
        odo.update(0.5, WORLD, ALL)


def test_bad_config_is_named():
    with pytest.raises(OdometryError, match='slip_fraction'):
        OdometryConfig(slip_fraction=-1.0)
    with pytest.raises(OdometryError, match='min_feet'):
        OdometryConfig(min_feet=1)
