"""The one shape of IMU data: a sample (:class:`ImuReading`) and a stamped series (:class:`ImuSeries`).

What the trunk's IMU measures, in the units and frames of ``sensor_msgs/msg/Imu`` on the contract's
``/imu``: the orientation of the body as a unit quaternion ``(w, x, y, z)`` in a gravity-aligned
frame, the specific force ``accel`` in the body frame [m/s^2] (about ``+g`` up for a trunk at rest),
and the body-frame angular velocity ``gyro`` [rad/s].

The simulated plant emits one :class:`ImuReading` per sample, the leg odometry takes one, and the
bag loader (:mod:`hexapod_sim.bagio.contents`) and the discrepancy analysis hold a whole recording
as an :class:`ImuSeries`. :meth:`ImuSeries.from_readings` and :meth:`ImuSeries.reading` are the one
conversion between the two.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Iterable

import numpy as np


@dataclass(frozen=True)
class ImuReading:
    """One IMU sample; a part the IMU does not give (or a consumer does not need) is None."""

    t_s: float | None = None
    quat_wxyz: np.ndarray | None = None     # orientation in a gravity-aligned frame
    accel: np.ndarray | None = None         # specific force in the body frame [m/s^2]
    gyro: np.ndarray | None = None          # angular velocity in the body frame [rad/s]


@dataclass(frozen=True)
class ImuSeries:
    """Stamped IMU samples: ``t_s`` (N,) [s], ``accel`` and ``gyro`` (N, 3), ``quat_wxyz`` (N, 4)
    or None where no orientation was recorded. Rows are in the order they were given."""

    t_s: np.ndarray
    accel: np.ndarray
    gyro: np.ndarray
    quat_wxyz: np.ndarray | None = None

    def __post_init__(self):
        n = self.t_s.shape[0] if self.t_s.ndim == 1 else -1
        shapes = {'accel': (self.accel, 3), 'gyro': (self.gyro, 3)}
        if self.quat_wxyz is not None:
            shapes['quat_wxyz'] = (self.quat_wxyz, 4)
        bad = [f'{k} {a.shape}' for k, (a, m) in shapes.items() if a.shape != (n, m)]
        if n < 0 or bad:
            raise ValueError(f'IMU series: stamps {self.t_s.shape} and {", ".join(bad) or "rows"} do not match')

    def __len__(self) -> int:
        return len(self.t_s)

    @classmethod
    def empty(cls, orientation: bool = True) -> 'ImuSeries':
        return cls(np.zeros(0), np.zeros((0, 3)), np.zeros((0, 3)), np.zeros((0, 4)) if orientation else None)

    @classmethod
    def from_readings(cls, readings: Iterable[ImuReading]) -> 'ImuSeries':
        """The series of samples that each carry a stamp, ``accel`` and ``gyro`` (and all or none an
        orientation)."""
        readings = list(readings)
        if not readings:
            return cls.empty()
        quat = [r.quat_wxyz for r in readings]
        if any(q is None for q in quat) and not all(q is None for q in quat):
            raise ValueError('IMU series: some samples have an orientation and some do not')
        return cls(np.array([float(r.t_s) for r in readings]),
                   np.array([r.accel for r in readings], dtype=float).reshape(-1, 3),
                   np.array([r.gyro for r in readings], dtype=float).reshape(-1, 3),
                   None if quat[0] is None else np.array(quat, dtype=float).reshape(-1, 4))

    def reading(self, i: int) -> ImuReading:
        """Sample ``i`` as an :class:`ImuReading`."""
        return ImuReading(float(self.t_s[i]), None if self.quat_wxyz is None else self.quat_wxyz[i].copy(),
                          self.accel[i].copy(), self.gyro[i].copy())

    def take(self, rows) -> 'ImuSeries':
        """The samples at ``rows`` (a boolean mask or indices), in that order."""
        return ImuSeries(self.t_s[rows], self.accel[rows], self.gyro[rows],
                         None if self.quat_wxyz is None else self.quat_wxyz[rows])

    def shifted(self, dt_s: float) -> 'ImuSeries':
        """The same samples stamped ``dt_s`` earlier (onto a clock that starts ``dt_s`` later)."""
        return ImuSeries(self.t_s - dt_s, self.accel, self.gyro, self.quat_wxyz)

    def finite(self) -> np.ndarray:
        """Boolean mask of the samples whose stamp, ``accel`` and ``gyro`` are all finite."""
        return (np.isfinite(self.t_s) & np.all(np.isfinite(self.accel), axis=1)
                & np.all(np.isfinite(self.gyro), axis=1))


__all__ = ['ImuReading', 'ImuSeries']
