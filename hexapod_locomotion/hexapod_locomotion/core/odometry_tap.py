"""Leg odometry fed by the servo bus the controller drives. No rclpy.

:class:`OdometryTap` is a transparent :class:`hexapod_model.bus.ServoBus` wrapper: the controller
is handed the tap instead of its bus, every call goes through unchanged, and the positions that
pass (each read, and the goals of a joint never read yet) give the six feet by forward kinematics.
At most every ``period_s`` of bus time, the feet the controller has on the ground
(:meth:`GaitController.contact_legs`) update one or more :class:`~hexapod_locomotion.core.odometry.LegOdometry`
(with and without the IMU side by side, for instance). A node whose bus master reads joints on a
schedule of its own (``/joint_states``) hands those reads in with :meth:`observe`.
"""
from __future__ import annotations

from typing import Callable

import numpy as np

from hexapod_locomotion.core.odometry import LegOdometry, OdometryEstimate
from hexapod_model.bus import ServoBus
from hexapod_model.contract import stamp_dict
from hexapod_model.description import JOINT_ROLES, LEGS, Robot, joint_name
from hexapod_model.imu import ImuReading
from hexapod_model.kinematics import forward

ODOMETRY_PERIOD_S = 0.02     # update period [s of bus time]: the bus reads a leg's 3 joints in ~4 ms
HANDOVER_S = 0.05            # longest time lifting feet stand in for landed ones not yet read


class OdometryTap(ServoBus):
    """``estimators``: (odometry, uses the IMU) pairs, the first is :attr:`estimate`'s;
    ``imu``: returns the latest :class:`ImuReading` or None; ``on_estimate(estimate)`` after each
    update of the first estimator."""

    def __init__(self, bus, robot: Robot, contact_legs: Callable[[], np.ndarray],
                 estimators: list[tuple[LegOdometry, bool]], imu: Callable[[], ImuReading | None] | None = None,
                 period_s: float = ODOMETRY_PERIOD_S, on_estimate: Callable[[OdometryEstimate], None] | None = None):
        self.bus = bus
        self.robot = robot
        self.contact_legs = contact_legs
        self.estimators = estimators
        self.imu = imu
        self.period_s = period_s
        self.on_estimate = on_estimate
        self.read: dict[str, float] = {}
        self.read_t: dict[str, float] = {}
        self._air_t = np.full(6, -np.inf)       # last update at which each foot was off the ground
        self.goal: dict[str, float] = {}
        self._next_t: float | None = None
        self._contact: np.ndarray | None = None
        self._used = np.zeros(6, bool)            # feet handed to the odometry at the last update
        self._handover = np.zeros(6, bool)
        self._lift_t = -np.inf

    # -- ServoBus, passed through
    @property
    def t_com_s(self) -> float:
        return self.bus.t_com_s

    def now(self) -> float:
        return self.bus.now()

    def sync_write(self, goals_rad) -> float:
        t = self.bus.sync_write(goals_rad)
        self.goal.update(goals_rad)
        self._maybe_update(t)
        return t

    def read_position(self, joint: str):
        theta, stamp = self.bus.read_position(joint)
        self.read[joint], self.read_t[joint] = float(theta), float(stamp)
        self._maybe_update(stamp)
        return theta, stamp

    def wait_until(self, t: float) -> None:
        self.bus.wait_until(t)

    # -- odometry
    def observe(self, names, positions, stamp_s: float) -> None:
        """Joint positions read by the bus master on its own schedule (``/joint_states``)."""
        for n, p in zip(names, positions):
            self.read[n], self.read_t[n] = float(p), float(stamp_s)

    def fresh(self) -> np.ndarray:
        """Which feet have every joint read since the foot was last off the ground: a leg's coxa and
        tibia are not read during its swing-down, and a foot from their reads before it would jump."""
        return np.array([min(self.read_t.get(joint_name(leg, r), -np.inf) for r in JOINT_ROLES) > self._air_t[leg - 1]
                         for leg in LEGS])

    def feet(self) -> np.ndarray | None:
        """The six feet in the body frame from the latest read of each joint (its goal if never read);
        None until every joint is known."""
        out = np.empty((6, 3))
        for leg in LEGS:
            th = []
            for r in JOINT_ROLES:
                j = joint_name(leg, r)
                v = self.read.get(j, self.goal.get(j))
                if v is None:
                    return None
                th.append(v)
            out[leg - 1] = forward(self.robot, leg, th)
        return out

    def _maybe_update(self, t: float) -> None:
        if self._next_t is not None and t < self._next_t - 1e-12 \
                and np.array_equal(self.contact_legs(), self._contact):
            return
        self.update(t)

    def phase_done(self) -> OdometryEstimate | None:
        """Update now: call after each gait phase (the landed feet are on the ground before the next
        group lifts; without an update in between the odometry would see no foot in both sets)."""
        return self.update(self.bus.now())

    def update(self, t: float) -> OdometryEstimate | None:
        feet = self.feet()
        if feet is None:
            return None
        self._next_t = t + self.period_s
        ctrl = self.contact_legs()
        lifted = ctrl < self._contact if self._contact is not None else np.zeros(6, bool)
        self._contact = ctrl
        self._air_t[~ctrl] = t
        fresh = self.fresh()
        # Hand-over: feet that have just landed count once every joint of theirs has been read since; the
        # feet lifting meanwhile (their footholds held at the start of the swing-up) carry the odometry
        # until then, at most HANDOVER_S.
        self._handover = (self._handover | (lifted & self._used)) & ~ctrl
        if lifted.any():
            self._lift_t = t
        contact = (ctrl & fresh) | self._handover
        if not (ctrl & ~fresh).any() or t - self._lift_t > HANDOVER_S:
            self._handover = np.zeros(6, bool)        # from the next update on
        self._used = contact
        imu = self.imu() if self.imu is not None else None
        first = None
        for odo, use_imu in self.estimators:
            e = odo.update(t, feet, contact, imu if use_imu else None, plane=ctrl & fresh)
            first = e if first is None else first
        if first is not None and self.on_estimate is not None:
            self.on_estimate(first)
        return first

    @property
    def feet_used(self) -> np.ndarray:
        """Which feet (legs 1..6) the last update took as on the ground."""
        return self._used.copy()

    @property
    def estimate(self) -> OdometryEstimate | None:
        return self.estimators[0][0].estimate if self.estimators else None


def odometry_dict(e: OdometryEstimate, frame_id: str = 'odom', child_frame_id: str = 'base_link') -> dict:
    """``nav_msgs/msg/Odometry`` of an estimate, as the plain dict the bag writer encodes (and the node
    copies into its message): pose in ``frame_id``, twist in ``child_frame_id``, covariances row-major."""
    x, y, z, w = e.quat_xyzw()
    return {'header': {'stamp': stamp_dict(e.t_s), 'frame_id': frame_id}, 'child_frame_id': child_frame_id,
            'pose': {'pose': {'position': dict(zip('xyz', (float(v) for v in e.position))),
                              'orientation': {'x': x, 'y': y, 'z': z, 'w': w}},
                     'covariance': [float(v) for v in e.pose_cov.ravel()]},
            'twist': {'twist': {'linear': dict(zip('xyz', (float(v) for v in e.linear))),
                                'angular': dict(zip('xyz', (float(v) for v in e.angular)))},
                      'covariance': [float(v) for v in e.twist_cov.ravel()]}}
