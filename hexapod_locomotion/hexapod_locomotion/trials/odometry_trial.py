"""Leg odometry in a simulated trial, and its drift against the simulator's truth. No rclpy.

:class:`TrialOdometry` runs two leg odometries side by side on the trial's bus (one with the sim's
IMU, one from the legs alone), records both tracks and writes the first to the bag as ``/odom``.
:func:`drift` compares a track with the truth: position error as a percentage of the distance
walked, yaw error per metre, and the walk's own heading and line errors against where it started; and
how much of the yaw error built up while a foot the odometry took as on the ground was off it in the
simulation (the contact the controller believes, against the sim's foot contacts). Beside the line:
where the odometry itself put the body off the line (what the course correction saw and acted on),
and how far the feet the odometry took as standing moved in the world meanwhile (slid, or off the
ground; truth): a leg odometry takes those feet as fixed, so their motion is its error, and no
controller acting on it can remove what it does not see.
"""
from __future__ import annotations

import math

import numpy as np
from scipy.spatial.transform import Rotation

from hexapod_locomotion.core.odometry import LegOdometry, OdometryEstimate, wrap_angle
from hexapod_locomotion.core.odometry_tap import OdometryTap, odometry_dict
from hexapod_model.contract import MSG_TYPES, ODOM
from hexapod_model.imu import ImuReading

PATH_SAMPLE_S = 0.5          # the distance walked: truth path length sampled this often (no body sway)


class TrialOdometry:
    """``probe``: the trial's :class:`~hexapod_locomotion.trials.trial_runner.ProbeBus`; ``imu_first``: the
    odometry the tap reports first (``estimate``, the course correction, ``/odom``) uses the IMU."""

    def __init__(self, probe, robot, controller, imu_first: bool = True, recorder=None,
                 frames: tuple[str, str] = ('odom', 'base_link')):
        self.probe = probe
        self.recorder = recorder
        self.frames = frames
        self.odometry = {'imu': LegOdometry(), 'legs': LegOdometry()}
        order = ('imu', 'legs') if imu_first else ('legs', 'imu')
        self.tracks: dict[str, list[tuple[float, float, float, float]]] = {k: [] for k in order}
        self.off_ground: list[bool] = []     # per update: a foot the odometry used was off the ground (truth)
        # per update: the mean horizontal world motion [m] since the last update of the feet used at both (truth)
        self.feet_motion: list[tuple[float, float]] = []
        self._feet_world: tuple[np.ndarray, np.ndarray] | None = None    # (world feet, used) at the last update
        self.tap = OdometryTap(probe, robot, controller.contact_legs,
                               [(self.odometry[k], k == 'imu') for k in order], imu=self._imu,
                               on_estimate=self._on_estimate)

    def _imu(self) -> ImuReading | None:
        if not self.probe.imu_rpy:
            return None
        r, p, y = self.probe.imu_rpy[-1]
        x, y_, z, w = Rotation.from_euler('ZYX', [y, p, r]).as_quat()
        return ImuReading(quat_wxyz=np.array([w, x, y_, z]))

    def _on_estimate(self, first: OdometryEstimate) -> None:
        for k in self.tracks:
            e = self.odometry[k].estimate
            self.tracks[k].append((e.t_s, float(e.position[0]), float(e.position[1]), float(e.rpy[2])))
        touch = self.probe.sim.feet_touching_last_step()        # no collision pass per update
        used = self.tap.feet_used
        self.off_ground.append(bool(np.any(used & ~touch)))
        world = self.probe.sim.feet_at_last_step()           # no kinematics pass per update either
        moved = (0.0, 0.0)
        if self._feet_world is not None:
            both = used & self._feet_world[1]
            if both.any():
                moved = tuple(float(v) for v in np.mean(world[both, :2] - self._feet_world[0][both, :2], axis=0))
        self.feet_motion.append(moved)
        self._feet_world = (world, used)
        if self.recorder is not None:
            self.recorder.write(ODOM, MSG_TYPES[ODOM], odometry_dict(first, *self.frames), first.t_s)

    def drift(self, truth_t, truth_xyz, truth_quat_wxyz, window_s: float = 0.0) -> dict:
        """Per odometry (``imu``, ``legs``): :func:`drift` of its track."""
        return {k: drift(tr, truth_t, truth_xyz, truth_quat_wxyz, window_s, self.off_ground, self.feet_motion)
                for k, tr in self.tracks.items() if tr}


def _truth_yaw(quat_wxyz) -> np.ndarray:
    q = np.asarray(quat_wxyz, dtype=float)
    return Rotation.from_quat(q[:, [1, 2, 3, 0]]).as_euler('ZYX')[:, 0]


def drift(track, truth_t, truth_xyz, truth_quat_wxyz, window_s: float = 0.0, off_ground=None,
          feet_motion=None) -> dict:
    """Odometry ``track`` [(t, x, y, yaw)] against the truth (times, positions, quaternions w x y z).

    Both poses are taken relative to their own at the track's first time. Returns the distance walked
    (truth path length at ``PATH_SAMPLE_S``), the final position error [m] and in % of that distance,
    the final yaw error [deg] and per metre, and the truth's own final heading change [deg] and
    distance from the start line [m] (how straight the walk was), at the end and as means over the last
    ``window_s`` (a gait cycle: a gait sways the body within each cycle). ``off_ground``: per track
    sample, whether a foot the odometry used was off the ground; then also the share of samples so
    flagged and the signed yaw error [deg] built up over the intervals ending at them and elsewhere
    (the two add up to the final yaw error, unwrapped). The odometry's own distance from its start line
    (a mean over the same window, in its start frame) is ``odometry_line_cycle_mean_m``. ``feet_motion``:
    per track sample, the mean horizontal world motion (x, y) [m] since the sample before of the feet the
    odometry used at both; then also their total along and across the start heading [m] (the first
    sample's is not counted: it has no sample before)."""
    tr = np.asarray(track, dtype=float)
    t = np.asarray(truth_t, dtype=float)
    xyz = np.asarray(truth_xyz, dtype=float)
    yaw = np.unwrap(_truth_yaw(truth_quat_wxyz))
    t0, t1 = tr[0, 0], tr[-1, 0]

    def at(ts):
        return np.array([np.interp(ts, t, xyz[:, 0]), np.interp(ts, t, xyz[:, 1])]), float(np.interp(ts, t, yaw))
    p0, y0 = at(t0)
    p1, y1 = at(t1)
    c, s = math.cos(y0), math.sin(y0)
    to_start = np.array([[c, s], [-s, c]])                  # world -> the truth's start heading frame
    rel = to_start @ (p1 - p0)                              # truth displacement in the start heading frame
    samples = np.arange(t0, t1, PATH_SAMPLE_S).tolist() + [t1]
    pts = np.array([at(ts)[0] for ts in samples])
    dist = float(np.sum(np.linalg.norm(np.diff(pts, axis=0), axis=1))) if len(pts) > 1 else 0.0
    # the odometry's displacement in its own start frame
    oc, os_ = math.cos(tr[0, 3]), math.sin(tr[0, 3])
    odo_to_start = np.array([[oc, os_], [-os_, oc]])
    odo_rel = odo_to_start @ (tr[-1, 1:3] - tr[0, 1:3])
    err = float(np.linalg.norm(odo_rel - rel))
    yaw_err = math.degrees(abs(wrap_angle((tr[-1, 3] - tr[0, 3]) - (y1 - y0))))
    ts = t[(t >= t1 - window_s) & (t <= t1)] if window_s > 0 else np.array([t1])
    ts = ts if len(ts) else np.array([t1])
    head_mean = float(np.mean([at(x)[1] for x in ts])) - y0
    line_mean = float(np.mean([(to_start @ (at(x)[0] - p0))[1] for x in ts]))
    in_window = tr[tr[:, 0] >= ts[0] - 1e-9]
    odo_line = float(np.mean((odo_to_start @ (in_window[:, 1:3] - tr[0, 1:3]).T)[1]))
    out = {'distance_m': dist, 'position_error_m': err,
           'position_error_pct': 100.0 * err / dist if dist > 0 else math.nan,
           'yaw_error_deg': yaw_err, 'yaw_error_deg_per_m': yaw_err / dist if dist > 0 else math.nan,
           'heading_change_deg': math.degrees(y1 - y0), 'line_offset_m': float(rel[1]),
           'heading_cycle_mean_deg': math.degrees(head_mean), 'line_cycle_mean_m': line_mean,
           'odometry_line_cycle_mean_m': odo_line, 'duration_s': float(t1 - t0)}
    if off_ground is not None:
        flag = np.asarray(off_ground, dtype=bool)
        if len(flag) != len(tr):
            raise ValueError(f'off_ground has {len(flag)} samples, the track {len(tr)}')
        step = np.diff(np.unwrap(tr[:, 3]) - np.interp(tr[:, 0], t, yaw))
        out.update(off_ground_share=float(flag.mean()),
                   yaw_error_off_ground_deg=math.degrees(float(step[flag[1:]].sum())),
                   yaw_error_elsewhere_deg=math.degrees(float(step[~flag[1:]].sum())))
    if feet_motion is not None:
        moved = np.asarray(feet_motion, dtype=float).reshape(-1, 2)
        if len(moved) != len(tr):
            raise ValueError(f'feet_motion has {len(moved)} samples, the track {len(tr)}')
        along, across = to_start @ moved[1:].sum(axis=0)
        out.update(feet_moved_along_m=float(along), feet_moved_across_m=float(across))
    return out
