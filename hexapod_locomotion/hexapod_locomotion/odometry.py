"""Leg odometry: the body's motion from the feet on the ground, fused with an IMU when one exists.
Pure numpy: time, foot positions, contacts and IMU samples are arguments.

A foot on the ground does not move in the world, so between two updates the body moved by the
rigid motion that carries the feet in contact at both (their body-frame positions from the forward
kinematics of the servo reads) from where they are now to where they were before. Each update:

1. roll and pitch: the IMU's orientation when given, else the plane of the feet in contact (the
   body leveled against the ground they stand on: exact on flat ground, the mean slope of the
   footholds on rough ground);
2. the feet are rotated into the gravity-aligned heading frame (body frame without roll and pitch);
3. a least-squares planar rigid fit (2-D Kabsch) between the feet in contact in both updates gives
   the yaw increment and the horizontal displacement; the mean vertical offset of those feet the
   height change;
4. with an IMU, the yaw increment is fused with the IMU's (orientation difference, else the yaw rate
   times the interval), weighted by their variances;
5. the pose covariance grows by the fit's residual and a slip term per metre walked, propagated
   through the heading (an error in yaw becomes a lateral error as the robot walks on).

Frames (REP 103/105): ``odom`` fixed where odometry started, z up; the body frame x forward, y left,
z up. The pose is (x, y, z) and (roll, pitch, yaw) of the body in ``odom``; the twist is in the body
frame. Covariances are 6x6 in the order of ``nav_msgs/Odometry`` (x, y, z, roll, pitch, yaw).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial.transform import Rotation


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
    # fewer feet in contact at both updates than this: no fit, the pose holds (and its covariance grows)
    min_feet: int = 2

    def __post_init__(self):
        for name in ('foot_sigma_m', 'slip_fraction', 'yaw_slip_rad_per_m', 'gyro_sigma_rad_s', 'imu_tilt_sigma_rad'):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise OdometryError(f'odometry {name} must be a finite number > 0, got {v!r}')
        if not (isinstance(self.min_feet, int) and self.min_feet >= 2):
            raise OdometryError(f'odometry min_feet must be an integer >= 2 (a yaw needs two feet), got {self.min_feet!r}')


@dataclass(frozen=True)
class ImuReading:
    """What the odometry takes from an IMU: orientation in a gravity-aligned frame (w, x, y, z) and/or
    the body-frame angular velocity [rad/s]. Either may be None."""

    quat_wxyz: np.ndarray | None = None
    ang_vel_rad_s: np.ndarray | None = None


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


def planar_fit(before: np.ndarray, after: np.ndarray) -> tuple[float, np.ndarray, float]:
    """Least-squares rigid motion in the plane: (dyaw, d_xy, rms residual) with
    ``before[:, :2] ~ Rz(dyaw) @ after[:, :2] + d_xy`` (2-D Kabsch; n >= 2 points)."""
    p, q = before[:, :2], after[:, :2]
    pc, qc = p - p.mean(axis=0), q - q.mean(axis=0)
    dyaw = math.atan2(float(np.sum(qc[:, 0] * pc[:, 1] - qc[:, 1] * pc[:, 0])), float(np.sum(qc * pc)))
    c, s = math.cos(dyaw), math.sin(dyaw)
    rot = np.array([[c, -s], [s, c]])
    d = p.mean(axis=0) - rot @ q.mean(axis=0)
    res = p - (q @ rot.T + d)
    return dyaw, d, float(math.sqrt(np.mean(np.sum(res ** 2, axis=1))))


@dataclass
class LegOdometry:
    """Integrates the body pose from successive stance-foot sets (see the module doc)."""

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
        self._feet: np.ndarray | None = None       # level-frame feet of the last update (6 x 3)
        self._contact: np.ndarray | None = None
        self._imu_yaw: float | None = None
        self._last = None

    def update(self, t_s: float, feet_body, contact, imu: ImuReading | None = None) -> OdometryEstimate:
        """One update at time ``t_s`` from the six feet in the body frame (6 x 3, rows legs 1..6) and
        which of them are on the ground (6 booleans); ``imu`` optional."""
        cfg = self.config
        feet = np.asarray(feet_body, dtype=float)
        contact = np.asarray(contact, dtype=bool)
        if feet.shape != (6, 3) or contact.shape != (6,):
            raise OdometryError(f'odometry needs 6 feet (6 x 3) and 6 contact flags, got {feet.shape} and {contact.shape}')
        if not math.isfinite(t_s) or (self.t_s is not None and t_s < self.t_s):
            raise OdometryError(f'odometry time must be finite and not go back, got {t_s!r} after {self.t_s!r}')
        if not np.all(np.isfinite(feet[contact])):
            raise OdometryError('odometry: a foot in contact has a non-finite position')
        dt = 0.0 if self.t_s is None else t_s - self.t_s

        # 1. tilt
        imu_quat = None if imu is None or imu.quat_wxyz is None else np.asarray(imu.quat_wxyz, dtype=float)
        if imu_quat is not None and not (imu_quat.shape == (4,) and np.all(np.isfinite(imu_quat))
                                         and np.linalg.norm(imu_quat) > 0):
            raise OdometryError(f'odometry: IMU orientation must be 4 finite numbers, not all 0, got {imu_quat!r}')
        gyro = None if imu is None or imu.ang_vel_rad_s is None else np.asarray(imu.ang_vel_rad_s, dtype=float)
        if gyro is not None and not (gyro.shape == (3,) and np.all(np.isfinite(gyro))):
            raise OdometryError(f'odometry: IMU angular velocity must be 3 finite numbers, got {gyro!r}')
        imu_yaw = None
        if imu_quat is not None:
            w, x, y, z = imu_quat
            rot = Rotation.from_quat([x, y, z, w]).as_matrix()
            self.roll, self.pitch, imu_yaw = _rpy(rot)
            tilt_var = cfg.imu_tilt_sigma_rad ** 2
        else:
            rp = plane_tilt(feet[contact]) if contact.sum() >= 3 else None
            if rp is not None:
                self.roll, self.pitch = rp
            spread = float(np.ptp(feet[contact, :2], axis=0).max()) if contact.sum() >= 2 else 0.1
            tilt_var = (cfg.foot_sigma_m / max(spread, 0.05)) ** 2 * 2
        tilt = Rotation.from_euler('YX', [self.pitch, self.roll]).as_matrix()
        level = feet @ tilt.T

        # 2.-4. the fit
        both = contact if self._contact is None else contact & self._contact
        n = int(both.sum())
        dyaw, d_xy, dz, used, resid = 0.0, np.zeros(2), 0.0, 0, 0.0
        var_yaw_leg = math.inf
        if self._feet is not None and n >= cfg.min_feet:
            dyaw, d_xy, resid = planar_fit(self._feet[both], level[both])
            dz = float(np.mean(self._feet[both, 2] - level[both, 2]))
            used = n
            spread2 = float(np.mean(np.sum((level[both, :2] - level[both, :2].mean(axis=0)) ** 2, axis=1)))
            sig2 = cfg.foot_sigma_m ** 2 + resid ** 2
            var_yaw_leg = 2 * sig2 / (n * max(spread2, 1e-4)) + (cfg.yaw_slip_rad_per_m * float(np.hypot(*d_xy))) ** 2
        if imu_yaw is not None and self._imu_yaw is not None:
            imu_dyaw, var_imu = wrap_angle(imu_yaw - self._imu_yaw), (cfg.gyro_sigma_rad_s * dt) ** 2
        elif gyro is not None and dt > 0:
            # the body's yaw rate in the level frame from the body-frame rate: R_tilt @ omega, z
            imu_dyaw, var_imu = float((tilt @ gyro)[2]) * dt, (cfg.gyro_sigma_rad_s * dt) ** 2
        else:
            imu_dyaw, var_imu = None, math.inf
        if imu_dyaw is not None and used:
            w_leg = var_imu / (var_imu + var_yaw_leg) if var_imu + var_yaw_leg > 0 else 0.0
            dyaw = w_leg * dyaw + (1 - w_leg) * imu_dyaw
            var_yaw = var_imu * var_yaw_leg / (var_imu + var_yaw_leg) if var_imu + var_yaw_leg > 0 else 0.0
        elif imu_dyaw is not None:
            dyaw, var_yaw = imu_dyaw, var_imu
        else:
            var_yaw = var_yaw_leg if used else 0.0
        if imu_yaw is not None:
            self._imu_yaw = imu_yaw

        # 5. integrate, propagate the covariance of (x, y, yaw) and z
        c0, s0 = math.cos(self.yaw), math.sin(self.yaw)
        d_world = np.array([c0 * d_xy[0] - s0 * d_xy[1], s0 * d_xy[0] + c0 * d_xy[1]])
        step = float(np.hypot(*d_xy))
        jac = np.eye(3)
        jac[0, 2], jac[1, 2] = -d_world[1], d_world[0]
        idx = [0, 1, 5]
        P = self.cov[np.ix_(idx, idx)]
        var_xy = ((cfg.foot_sigma_m ** 2 + resid ** 2) / max(used, 1) if used else 0.0) + (cfg.slip_fraction * step) ** 2
        P = jac @ P @ jac.T + np.diag([var_xy, var_xy, var_yaw if math.isfinite(var_yaw) else 0.0])
        self.cov[np.ix_(idx, idx)] = P
        self.cov[2, 2] += (cfg.foot_sigma_m ** 2 / max(used, 1) if used else 0.0) + (cfg.slip_fraction * abs(dz)) ** 2
        self.cov[3, 3] = self.cov[4, 4] = tilt_var
        self.position[:2] += d_world
        self.position[2] += dz
        if self._feet is None and contact.any():
            # odom's origin on the ground under the start: z is the body's height above its feet
            self.position[2] = -float(np.mean(level[contact, 2]))
        self.yaw = wrap_angle(self.yaw + dyaw)
        self.distance_m += step

        if dt > 0:
            lin = np.array([d_xy[0], d_xy[1], dz]) / dt
            ang = np.array([0.0, 0.0, dyaw / dt])
        else:
            lin, ang = (np.zeros(3), np.zeros(3)) if self._last is None else (self._last.linear, self._last.angular)
        tw = np.zeros((6, 6))
        if dt > 0:
            v_var = (cfg.foot_sigma_m ** 2 + resid ** 2) / max(used, 1) * 2 / dt ** 2 + (cfg.slip_fraction * step / dt) ** 2
            tw[0, 0] = tw[1, 1] = tw[2, 2] = v_var
            tw[3, 3] = tw[4, 4] = tilt_var / dt ** 2
            tw[5, 5] = (var_yaw if math.isfinite(var_yaw) else 0.0) / dt ** 2
        if not used and imu_dyaw is None and self._feet is not None:
            tw[:] = np.diag([1e3] * 6)                      # no information on the motion at this update
        self._feet, self._contact, self.t_s = level, contact.copy(), float(t_s)
        self._last = OdometryEstimate(float(t_s), self.position.copy(), np.array([self.roll, self.pitch, self.yaw]),
                                      lin, ang, self.cov.copy(), tw, used, self.distance_m)
        return self._last

    @property
    def estimate(self) -> OdometryEstimate | None:
        return self._last
