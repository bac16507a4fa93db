"""Leg odometry: the body's motion from the feet on the ground, fused with an IMU when one exists.
Pure numpy: time, foot positions, contacts and IMU samples are arguments.

A foot on the ground does not move in the world, so since a *keyframe* (the last time a foot joined
the feet on the ground) the body moved by the rigid motion that carries the feet in contact then and
now (their body-frame positions from the forward kinematics of the servo reads) from where they are
now to where they were then. Each update:

1. roll and pitch: the IMU's orientation when given, else the plane of the feet in contact (the
   body leveled against the ground they stand on: exact on flat ground, the mean slope of the
   footholds on rough ground);
2. the feet are rotated into the gravity-aligned heading frame (body frame without roll and pitch);
3. a least-squares planar rigid fit (2-D Kabsch) between the feet in contact at the keyframe and now
   gives the yaw and horizontal displacement since the keyframe;
4. with an IMU, that yaw is fused with the IMU's since the keyframe (orientation difference, else the
   integrated yaw rate), weighted by their variances; where the two differ by more than
   ``slip_gate_sigma`` standard deviations the feet taken as standing did not stand still (they
   slipped together, or a leg stalled on a block lifted the body off them and they followed their
   commands in the air: neither leaves a residual in the fit) and the IMU's yaw alone counts;
5. the displacement is fitted again under that yaw (the yaw the pose takes, not the legs' own): each
   foot's displacement is compared with the feet's median, and among three feet or more one more than
   ``slip_foot_gate_m`` off it is left out (it slid, or hangs, while the others stand); the mean of the
   rest is the displacement, the mean vertical offset of the same feet the height change;
6. the pose covariance is the keyframe's grown by the fit's residual and a slip term per metre
   walked, propagated through the heading (an error in yaw becomes a lateral error as the robot walks
   on).

Frames (REP 103/105): ``odom`` fixed where odometry started, z up; the body frame x forward, y left,
z up. The pose is (x, y, z) and (roll, pitch, yaw) of the body in ``odom``; the twist is in the body
frame. Covariances are 6x6 in the order of ``nav_msgs/Odometry`` (x, y, z, roll, pitch, yaw).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np
from scipy.spatial.transform import Rotation

from hexapod_model.imu import ImuReading

TIME_JITTER_S = 1e-6      # [s] an earlier time by less than this is the same instant (float rounding of ns stamps)


class OdometryError(ValueError):
    """Bad input to the odometry (the message names it)."""


@dataclass(frozen=True)
class OdometryConfig:
    """Noise model of the leg odometry (standard deviations)."""

    # one foot's position from the servo reads [m]: a tick (0.29 deg) of each joint over a 12-18 cm
    # leg is about 1 mm; compliance under load and the foot's rolling contact add a few
    foot_sigma_m: float = 0.003
    # slip of the feet on the ground, as a fraction of the distance walked (horizontal and vertical)
    slip_fraction: float = 0.03
    # heading slip per metre walked [rad/m] (feet twisting on their contact points)
    yaw_slip_rad_per_m: float = 0.03
    # IMU: yaw-rate noise [rad/s] (a MEMS gyro's white noise after its low-pass) and the
    # orientation's roll/pitch uncertainty [rad]
    gyro_sigma_rad_s: float = 0.005
    imu_tilt_sigma_rad: float = 0.01
    # the legs' and the IMU's yaw since the keyframe further apart than this many standard deviations:
    # the feet taken as standing did not stand still (a leg stalled on a block turns the body while they
    # slip or hang), the IMU's yaw alone counts. Tripod on the blocks, a stall trial (seed 1, 40 s,
    # correction on): fused by the variances alone the legs' 33 degrees of error left the estimate 2.6
    # degrees off the truth, and the walk's heading with it
    slip_gate_sigma: float = 3.0
    # a foot whose displacement since the keyframe is further than this from the feet's median is left
    # out of the displacement (three feet or more): it slid, or hangs, while the others stand. About 3
    # standard deviations of the difference of two feet's read noise (foot_sigma_m)
    slip_foot_gate_m: float = 0.01
    # fewer feet in contact at both updates than this: no fit, the pose holds (and its covariance grows)
    min_feet: int = 2

    def __post_init__(self):
        for name in ('foot_sigma_m', 'slip_fraction', 'yaw_slip_rad_per_m', 'gyro_sigma_rad_s', 'imu_tilt_sigma_rad',
                     'slip_gate_sigma', 'slip_foot_gate_m'):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise OdometryError(f'odometry {name} must be a finite number > 0, got {v!r}')
        if not (isinstance(self.min_feet, int) and self.min_feet >= 2):
            raise OdometryError(f'odometry min_feet must be an integer >= 2 (a yaw needs two feet), got {self.min_feet!r}')


@dataclass(frozen=True)
class OdometryEstimate:
    t_s: float
    position: np.ndarray            # (x, y, z) of the body in odom [m]
    rpy: np.ndarray                 # (roll, pitch, yaw) [rad]
    linear: np.ndarray              # body-frame velocity (vx, vy, vz) [m/s] over the last update
    angular: np.ndarray             # body-frame angular velocity (0, 0, wz) [rad/s] (yaw rate only)
    pose_cov: np.ndarray            # 6x6 (x, y, z, roll, pitch, yaw)
    twist_cov: np.ndarray           # 6x6 (vx, vy, vz, wx, wy, wz)
    feet_used: int                  # feet in the last fit (0: no fit at this update)
    distance_m: float               # horizontal path length so far

    def quat_xyzw(self) -> tuple[float, float, float, float]:
        q = Rotation.from_euler('ZYX', [self.rpy[2], self.rpy[1], self.rpy[0]]).as_quat()
        return tuple(float(v) for v in q)


def wrap_angle(a: float) -> float:
    return (a + math.pi) % (2 * math.pi) - math.pi


def tilt_of(rot: np.ndarray) -> np.ndarray:
    """The roll-pitch part of a body orientation (yaw removed): R = Rz(yaw) @ tilt."""
    r, p, _ = _rpy(rot)
    return Rotation.from_euler('YX', [p, r]).as_matrix()


def _rpy(rot: np.ndarray) -> tuple[float, float, float]:
    yaw, pitch, roll = Rotation.from_matrix(rot).as_euler('ZYX')
    return float(roll), float(pitch), float(yaw)


def plane_tilt(feet_body: np.ndarray) -> tuple[float, float] | None:
    """(roll, pitch) of a body standing on the plane through ``feet_body`` (n x 3, n >= 3) taken as
    level; None when the feet are (nearly) collinear."""
    c = feet_body - feet_body.mean(axis=0)
    _, s, vt = np.linalg.svd(c)
    if len(feet_body) < 3 or s[1] < 1e-6:
        return None
    n = vt[2] if vt[2, 2] > 0 else -vt[2]          # the ground's up, in the body frame
    # body-frame up = R^T e_z = (-sin p, sin r cos p, cos r cos p)
    pitch = math.asin(float(np.clip(-n[0], -1.0, 1.0)))
    roll = math.atan2(float(n[1]), float(n[2]))
    return roll, pitch


def _rot2(a: float) -> np.ndarray:
    """The rotation by ``a`` in the plane (2 x 2)."""
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s], [s, c]])


def planar_fit(before: np.ndarray, after: np.ndarray) -> tuple[float, np.ndarray, float]:
    """Least-squares rigid motion in the plane: (dyaw, d_xy, rms residual) with
    ``before[:, :2] ~ Rz(dyaw) @ after[:, :2] + d_xy`` (2-D Kabsch; n >= 2 points)."""
    p, q = before[:, :2], after[:, :2]
    pc, qc = p - p.mean(axis=0), q - q.mean(axis=0)
    dyaw = math.atan2(float(np.sum(qc[:, 0] * pc[:, 1] - qc[:, 1] * pc[:, 0])), float(np.sum(qc * pc)))
    rot = _rot2(dyaw)
    d = p.mean(axis=0) - rot @ q.mean(axis=0)
    res = p - (q @ rot.T + d)
    return dyaw, d, float(math.sqrt(np.mean(np.sum(res ** 2, axis=1))))


class _LegFit(NamedTuple):
    """The legs' motion since the keyframe (steps 2-3 of the module doc, the displacement and height
    change as step 5 takes them) in the level frame."""

    dyaw: float            # yaw change [rad]
    d_xy: np.ndarray       # horizontal displacement [m]
    dz: float              # height change [m] (0 from the fit; step 5 sets it with the feet it keeps)
    step: float            # |d_xy| [m]
    var_legs: float        # the yaw's variance [rad^2] (inf without a fit)
    used: int              # feet in the fit (0: none)
    resid: float           # rms residual of the fit [m]
    sig2: float            # one foot's position variance with that residual [m^2]


def _fuse_yaw(fit: _LegFit, d_imu: float | None, var_imu: float, gate_sigma: float) -> tuple[float, float]:
    """Step 4: the legs' yaw change fused with the IMU's by their variances: ``(dyaw, var_yaw)``; the
    IMU's alone where they differ by more than ``gate_sigma`` standard deviations (the feet taken as
    standing did not stand still)."""
    if d_imu is not None and fit.used:
        tot = var_imu + fit.var_legs
        if abs(wrap_angle(fit.dyaw - d_imu)) > gate_sigma * math.sqrt(tot):
            return d_imu, var_imu
        w_legs = var_imu / tot if tot > 0 else 0.0
        return w_legs * fit.dyaw + (1 - w_legs) * d_imu, var_imu * fit.var_legs / tot if tot > 0 else 0.0
    if d_imu is not None:
        return d_imu, var_imu
    return fit.dyaw, fit.var_legs if fit.used else 0.0


@dataclass
class LegOdometry:
    """Integrates the body pose from the stance feet (see the module doc)."""

    config: OdometryConfig = field(default_factory=OdometryConfig)

    def __post_init__(self):
        self.reset()

    def reset(self, t_s: float | None = None) -> None:
        self.t_s = t_s
        self.position = np.zeros(3)
        self.yaw = 0.0
        self.roll = self.pitch = 0.0
        self.cov = np.zeros((6, 6))
        self.distance_m = 0.0
        self._key = None            # (feet level frame 6 x 3, contact, position, yaw, cov, imu yaw, t)
        self._imu_yaw: float | None = None
        self._gyro_yaw = 0.0        # yaw integrated from the gyro since the keyframe
        self._last: OdometryEstimate | None = None

    def _rekey(self, level: np.ndarray, contact: np.ndarray, t_s: float) -> None:
        self._key = (level, contact.copy(), self.position.copy(), self.yaw, self.cov.copy(), self._imu_yaw, t_s)
        self._gyro_yaw = 0.0

    def update(self, t_s: float, feet_body, contact, imu: ImuReading | None = None, plane=None) -> OdometryEstimate:
        """One update at time ``t_s`` from the six feet in the body frame (6 x 3, rows legs 1..6) and
        which of them are on the ground (6 booleans); ``imu`` optional; ``plane``: the feet whose plane
        gives roll and pitch without an IMU (default ``contact``; fewer than 3: the last tilt holds).

        The feet are fitted against a *keyframe*: the feet in contact when the current stance began
        (the last time a foot joined). Read noise (a tick is about 1 mm at the foot) then does not
        add up update after update, only once per keyframe."""
        t_s, feet, contact, imu_quat, gyro = self._checked(t_s, feet_body, contact, imu)
        dt = 0.0 if self.t_s is None else t_s - self.t_s
        prev_pos, prev_yaw = self.position.copy(), self.yaw
        tilt, tilt_var = self._tilt(feet, contact, imu_quat, plane)        # 1.
        level = feet @ tilt.T
        if gyro is not None and dt > 0:
            self._gyro_yaw += float((tilt @ gyro)[2]) * dt      # the level frame's yaw rate
        if self._key is None:
            if contact.any():       # odom's origin on the ground under the start: z is the height above the feet
                self.position[2] = -float(np.mean(level[contact, 2]))
            self._rekey(level, contact, t_s)
        key_contact = self._key[1]
        both = contact & key_contact
        fit = self._fit(level, both)                                       # 2.-3.
        d_imu, var_imu = self._imu_yaw_change(imu_quat, gyro, t_s - self._key[6])    # 4.
        dyaw, var_yaw = _fuse_yaw(fit, d_imu, var_imu, self.config.slip_gate_sigma)
        fit = self._displacement(fit, level, both, dyaw)                  # 5.
        self._advance_pose(fit, dyaw, var_yaw, d_imu, tilt_var, prev_pos, prev_yaw)   # 6.
        moved = self.position - prev_pos
        self.distance_m += float(np.hypot(moved[0], moved[1]))
        if fit.used < self.config.min_feet or bool(np.any(contact & ~key_contact)):
            self._rekey(level, contact, t_s)          # a foot joined (or too few are left): a new keyframe
        elif bool(np.any(key_contact & ~contact)):   # a foot left: its keyframe position is gone with it
            self._key = (self._key[0], both, *self._key[2:])
        lin, ang, tw = self._twist(fit, d_imu, tilt_var, moved, prev_yaw, dt)
        self.t_s = float(t_s)
        self._last = OdometryEstimate(float(t_s), self.position.copy(), np.array([self.roll, self.pitch, self.yaw]),
                                      lin, ang, self.cov.copy(), tw, fit.used, self.distance_m)
        return self._last

    def _checked(self, t_s: float, feet_body, contact, imu: ImuReading | None):
        """The inputs of :meth:`update` checked: ``(t_s, feet, contact, imu_quat, gyro)``, the time no
        earlier than the last update's (an instant computed two ways), the IMU's parts None if absent."""
        feet = np.asarray(feet_body, dtype=float)
        contact = np.asarray(contact, dtype=bool)
        if feet.shape != (6, 3) or contact.shape != (6,):
            raise OdometryError(f'odometry needs 6 feet (6 x 3) and 6 contact flags, got {feet.shape} and {contact.shape}')
        if not math.isfinite(t_s) or (self.t_s is not None and t_s < self.t_s - TIME_JITTER_S):
            raise OdometryError(f'odometry time must be finite and not go back, got {t_s!r} after {self.t_s!r}')
        if self.t_s is not None:
            t_s = max(t_s, self.t_s)     # the same instant computed two ways (4.497 after 4.497000000000001)
        if not np.all(np.isfinite(feet[contact])):
            raise OdometryError('odometry: a foot in contact has a non-finite position')
        imu_quat = None if imu is None or imu.quat_wxyz is None else np.asarray(imu.quat_wxyz, dtype=float)
        if imu_quat is not None and not (imu_quat.shape == (4,) and np.all(np.isfinite(imu_quat))
                                         and np.linalg.norm(imu_quat) > 0):
            raise OdometryError(f'odometry: IMU orientation must be 4 finite numbers, not all 0, got {imu_quat!r}')
        gyro = None if imu is None or imu.gyro is None else np.asarray(imu.gyro, dtype=float)
        if gyro is not None and not (gyro.shape == (3,) and np.all(np.isfinite(gyro))):
            raise OdometryError(f'odometry: IMU angular velocity must be 3 finite numbers, got {gyro!r}')
        return t_s, feet, contact, imu_quat, gyro

    def _tilt(self, feet: np.ndarray, contact: np.ndarray, imu_quat, plane) -> tuple[np.ndarray, float]:
        """Step 1: roll and pitch (and the IMU's yaw) from the IMU's orientation, else from the plane of
        the feet (the last tilt holds without one). Returns the tilt matrix and the tilt's variance."""
        cfg = self.config
        if imu_quat is not None:
            w, x, y, z = imu_quat
            self.roll, self.pitch, self._imu_yaw = _rpy(Rotation.from_quat([x, y, z, w]).as_matrix())
            tilt_var = cfg.imu_tilt_sigma_rad ** 2
        else:
            on = contact if plane is None else np.asarray(plane, dtype=bool) & contact
            rp = plane_tilt(feet[on]) if on.sum() >= 3 else None
            if rp is not None:
                self.roll, self.pitch = rp
            spread = float(np.ptp(feet[contact, :2], axis=0).max()) if contact.sum() >= 2 else 0.1
            tilt_var = (cfg.foot_sigma_m / max(spread, 0.05)) ** 2 * 2
        return Rotation.from_euler('YX', [self.pitch, self.roll]).as_matrix(), tilt_var

    def _fit(self, level: np.ndarray, both: np.ndarray) -> _LegFit:
        """Steps 2-3: the motion since the keyframe from the feet in contact then and now (``both``),
        in the level frame; no motion, and an infinite yaw variance, with fewer than ``min_feet``."""
        cfg = self.config
        key_feet = self._key[0]
        n = int(both.sum())
        if n < cfg.min_feet:
            return _LegFit(0.0, np.zeros(2), 0.0, 0.0, math.inf, 0, 0.0, 0.0)
        dyaw, d_xy, resid = planar_fit(key_feet[both], level[both])
        spread2 = float(np.mean(np.sum((level[both, :2] - level[both, :2].mean(axis=0)) ** 2, axis=1)))
        sig2 = cfg.foot_sigma_m ** 2 + resid ** 2
        step = float(np.hypot(*d_xy))
        var_legs = 2 * sig2 / (n * max(spread2, 1e-4)) + (cfg.yaw_slip_rad_per_m * step) ** 2
        return _LegFit(dyaw, d_xy, 0.0, step, var_legs, n, resid, sig2)

    def _displacement(self, fit: _LegFit, level: np.ndarray, both: np.ndarray, dyaw: float) -> _LegFit:
        """Step 5: ``fit`` with its displacement and height change fitted again under the yaw change
        ``dyaw`` (least squares given the rotation: the mean of the feet's own displacements; the same
        as the fit's where ``dyaw`` is the legs' own yaw), a foot that moved apart from the others left
        out (see ``slip_foot_gate_m``)."""
        if not fit.used:
            return fit
        before, now = self._key[0][both], level[both]
        each = before[:, :2] - now[:, :2] @ _rot2(dyaw).T
        keep = np.ones(len(each), bool)
        if len(each) >= 3:
            apart = np.linalg.norm(each - np.median(each, axis=0), axis=1) > self.config.slip_foot_gate_m
            if (~apart).sum() >= 2:
                keep = ~apart
        d_xy = each[keep].mean(axis=0)
        dz = float(np.mean(before[keep, 2] - now[keep, 2]))
        return fit._replace(d_xy=d_xy, dz=dz, step=float(np.hypot(*d_xy)))

    def _imu_yaw_change(self, imu_quat, gyro, span: float) -> tuple[float | None, float]:
        """Step 4: the IMU's yaw change since the keyframe ``span`` seconds ago (orientation difference,
        else the integrated yaw rate) and its variance; ``(None, inf)`` without one."""
        sigma = self.config.gyro_sigma_rad_s
        key_imu_yaw = self._key[5]
        if imu_quat is not None and key_imu_yaw is not None:
            return wrap_angle(self._imu_yaw - key_imu_yaw), (sigma * span) ** 2
        if gyro is not None:
            return self._gyro_yaw, (sigma * span) ** 2
        return None, math.inf

    def _advance_pose(self, fit: _LegFit, dyaw: float, var_yaw: float, d_imu, tilt_var: float,
                      prev_pos: np.ndarray, prev_yaw: float) -> None:
        """Step 6: the pose from the keyframe's (held without a fit), and its covariance grown by the
        fit's residual and the slip, propagated through the heading."""
        cfg = self.config
        used = fit.used
        _, _, key_pos, key_yaw, key_cov, _, _ = self._key
        if not used:                 # no foot to fit: hold the pose (the keyframe is renewed by update)
            key_pos, key_yaw, key_cov = prev_pos, prev_yaw if d_imu is None else key_yaw, self.cov
        d_xy = fit.d_xy
        c0, s0 = math.cos(key_yaw), math.sin(key_yaw)
        d_world = np.array([c0 * d_xy[0] - s0 * d_xy[1], s0 * d_xy[0] + c0 * d_xy[1]])
        self.position = key_pos + np.array([d_world[0], d_world[1], fit.dz])
        self.yaw = wrap_angle(key_yaw + dyaw)
        jac = np.eye(3)
        jac[0, 2], jac[1, 2] = -d_world[1], d_world[0]
        idx = [0, 1, 5]
        var_xy = (fit.sig2 / used if used else 0.0) + (cfg.slip_fraction * fit.step) ** 2
        cov = key_cov.copy()
        cov[np.ix_(idx, idx)] = jac @ key_cov[np.ix_(idx, idx)] @ jac.T + np.diag([var_xy, var_xy, var_yaw])
        cov[2, 2] = key_cov[2, 2] + (cfg.foot_sigma_m ** 2 / used if used else 0.0) + (cfg.slip_fraction * fit.dz) ** 2
        cov[3, 3] = cov[4, 4] = tilt_var
        self.cov = cov

    def _twist(self, fit: _LegFit, d_imu, tilt_var: float, moved: np.ndarray, prev_yaw: float, dt: float):
        """The twist over the last update, in the body's heading frame: ``(linear, angular, covariance)``
        (the last update's velocities at the same instant)."""
        cfg = self.config
        tw = np.zeros((6, 6))
        if dt > 0:
            c, s = math.cos(prev_yaw), math.sin(prev_yaw)
            lin = np.array([c * moved[0] + s * moved[1], -s * moved[0] + c * moved[1], moved[2]]) / dt
            ang = np.array([0.0, 0.0, wrap_angle(self.yaw - prev_yaw) / dt])
            v_var = 2 * (cfg.foot_sigma_m ** 2 + fit.resid ** 2) / max(fit.used, 1) / dt ** 2
            tw[0, 0] = tw[1, 1] = tw[2, 2] = v_var
            tw[3, 3] = tw[4, 4] = tilt_var / dt ** 2
            var_legs = fit.var_legs
            tw[5, 5] = 2 * (var_legs if d_imu is None else min(var_legs, (cfg.gyro_sigma_rad_s * dt) ** 2)) / dt ** 2 \
                if (fit.used or d_imu is not None) else 1e3
        else:
            lin, ang = (np.zeros(3), np.zeros(3)) if self._last is None else (self._last.linear, self._last.angular)
        return lin, ang, tw

    @property
    def estimate(self) -> OdometryEstimate | None:
        return self._last
