"""What the plant's sensors report: the battery, every servo's control table, the feet (evaluation-only
truth), and the IMU's world-to-body rotation."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class BatteryReading:
    t_s: float
    voltage_v: float
    current_a: float             # instantaneous (last firmware tick)
    power_w: float               # instantaneous (last firmware tick)
    energy_j: float              # drawn since reset


@dataclass(frozen=True)
class ServoTelemetry:
    """What each servo's control table would report (arrays in ``ALL_JOINTS`` order)."""

    t_s: float
    temperature_c: np.ndarray
    voltage_v: np.ndarray
    load_fraction: np.ndarray    # signed output torque / stall torque, in the servo's own direction
    error_bits: np.ndarray       # Protocol 1.0 error byte
    torque_enabled: np.ndarray


@dataclass(frozen=True)
class FootContacts:
    """Evaluation-only truth: per leg 1..6, whether the foot touches the terrain and the force on it."""

    t_s: float
    in_contact: np.ndarray       # (6,) bool
    force_world_n: np.ndarray    # (6, 3) total contact force on the foot geom, world frame


def rotate_to_body(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """R(q)^T v for rows of unit quaternions q (w, x, y, z) and vectors v (world -> body).

    v' = v + w t + u x t with t = 2 u x v and u = -(x, y, z) (the conjugate rotates world -> body).
    """
    w, ux, uy, uz = q[:, 0], -q[:, 1], -q[:, 2], -q[:, 3]
    vx, vy, vz = v[:, 0], v[:, 1], v[:, 2]
    tx, ty, tz = 2.0 * (uy * vz - uz * vy), 2.0 * (uz * vx - ux * vz), 2.0 * (ux * vy - uy * vx)
    return np.column_stack([vx + w * tx + uy * tz - uz * ty,
                            vy + w * ty + uz * tx - ux * tz,
                            vz + w * tz + ux * ty - uy * tx])
