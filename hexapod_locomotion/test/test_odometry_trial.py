"""Leg odometry in a simulated walk, against the simulator's truth (lock-stepped, deterministic)."""
import numpy as np
import pytest

from hexapod_locomotion.trials.odometry_trial import drift
from hexapod_locomotion.trials.trial_runner import TrialConfig, run_trial


def test_odometry_of_a_flat_walk_stays_within_the_drift_targets():
    """10 s of tripod on flat ground: position error at most 5 % of the distance, yaw at most 3 deg/m,
    with and without the IMU."""
    r = run_trial(TrialConfig(gait='tripod', terrain='flat', seed=0, duration_s=10.0))
    assert r.distance_m > 0.3
    for name in ('imu', 'legs'):
        o = r.odometry[name]
        assert o['distance_m'] == pytest.approx(r.path_length_m, rel=0.2)
        assert o['position_error_pct'] < 5.0, (name, o)
        assert o['yaw_error_deg_per_m'] < 3.0, (name, o)
        # the yaw error's two parts (by the sim's foot contacts) add up to it
        assert abs(o['yaw_error_off_ground_deg'] + o['yaw_error_elsewhere_deg']) == pytest.approx(o['yaw_error_deg'],
                                                                                                  abs=1e-9)
        assert 0.0 <= o['off_ground_share'] < 1.0
        # the feet it stood on hardly moved across the line on flat ground (truth), nor did it see the body off it
        assert abs(o['feet_moved_across_m']) < 0.003 and abs(o['odometry_line_cycle_mean_m']) < 0.005, (name, o)


def test_drift_of_a_track_that_is_the_truth_is_zero_and_of_a_short_one_is_its_error():
    t = np.linspace(0, 10, 101)
    xyz = np.c_[0.05 * t, np.zeros_like(t), np.full_like(t, 0.1)]
    quat = np.tile([1.0, 0, 0, 0], (len(t), 1))
    exact = [(ti, 0.05 * ti, 0.0, 0.0) for ti in t]
    d = drift(exact, t, xyz, quat, window_s=2.0)
    assert d['position_error_m'] == pytest.approx(0.0, abs=1e-12)
    assert d['distance_m'] == pytest.approx(0.5)
    short = [(ti, 0.045 * ti, 0.0, 0.0) for ti in t]           # 10 % short: 5 cm of 50
    assert drift(short, t, xyz, quat)['position_error_pct'] == pytest.approx(10.0)


def test_turning_in_place_with_the_correction_follows_the_commanded_rate():
    """Tripod on flat ground at 0.05 rad/s for 15 s: open loop the body turns 2/3 of the placed yaw (and less
    over the first cycle); with the correction within 10 % of the command over the whole walk."""
    rates = {}
    for c in (False, True):
        r = run_trial(TrialConfig(gait='tripod', terrain='flat', seed=0, duration_s=15.0, vx_mps=0.0, wz_rad_s=0.05,
                                  heading_correction=c))
        o = r.odometry['imu']
        rates[c] = np.radians(o['heading_change_deg']) / o['duration_s']
    assert rates[False] < 0.05 * 0.75
    assert rates[True] == pytest.approx(0.05, rel=0.1)


def test_drift_splits_the_yaw_error_by_whether_a_used_foot_was_off_the_ground():
    # the truth walks straight; the odometry's yaw turns 0.01 rad at each of the samples flagged and
    # -0.002 rad at each one that is not: the two parts add up to the final error
    t = np.linspace(0, 10, 101)
    xyz = np.c_[0.05 * t, np.zeros_like(t), np.full_like(t, 0.1)]
    quat = np.tile([1.0, 0, 0, 0], (len(t), 1))
    flag = (t > 3) & (t < 5)
    yaw = np.cumsum(np.where(flag, 0.01, -0.002) * (np.arange(len(t)) > 0))
    track = [(ti, 0.05 * ti, 0.0, y) for ti, y in zip(t, yaw)]
    d = drift(track, t, xyz, quat, off_ground=flag)
    assert d['off_ground_share'] == pytest.approx(flag.mean())
    assert d['yaw_error_off_ground_deg'] == pytest.approx(np.degrees(0.01 * flag.sum()))
    assert d['yaw_error_elsewhere_deg'] == pytest.approx(np.degrees(-0.002 * (len(t) - 1 - flag.sum())))
    assert 'off_ground_share' not in drift(track, t, xyz, quat)
    with pytest.raises(ValueError, match='off_ground has 3 samples'):
        drift(track, t, xyz, quat, off_ground=[True, False, True])


def test_drift_gives_the_odometry_own_line_and_the_motion_of_the_feet_it_stood_on():
    # the truth walks straight along x; the odometry drifts 2 cm to the left over the walk while the feet it
    # stood on slid 1 mm to the right at each sample after the first: it took them as fixed, so it moved
    # the body left where the body stayed on the line
    t = np.linspace(0, 10, 101)
    xyz = np.c_[0.05 * t, np.zeros_like(t), np.full_like(t, 0.1)]
    quat = np.tile([1.0, 0, 0, 0], (len(t), 1))
    track = [(ti, 0.05 * ti, 0.002 * ti, 0.0) for ti in t]
    moved = [(0.0, -0.001)] * len(t)
    d = drift(track, t, xyz, quat, window_s=2.0, feet_motion=moved)
    assert d['line_cycle_mean_m'] == pytest.approx(0.0, abs=1e-12)
    assert d['odometry_line_cycle_mean_m'] == pytest.approx(0.018, abs=1e-3)    # the mean over the last 2 s
    assert d['feet_moved_across_m'] == pytest.approx(-0.1) and d['feet_moved_along_m'] == pytest.approx(0.0)
    # across and along the start heading: for a walk heading along +y a slide in -x is across it, to the left
    yaw90 = np.tile([np.cos(np.pi / 4), 0, 0, np.sin(np.pi / 4)], (len(t), 1))
    d90 = drift(track, t, xyz[:, [1, 0, 2]], yaw90, feet_motion=[(-0.001, 0.0)] * len(t))
    assert d90['feet_moved_across_m'] == pytest.approx(0.1) and d90['feet_moved_along_m'] == pytest.approx(0.0, abs=1e-12)
    with pytest.raises(ValueError, match='feet_motion has 3 samples'):
        drift(track, t, xyz, quat, feet_motion=[(0.0, 0.0)] * 3)
