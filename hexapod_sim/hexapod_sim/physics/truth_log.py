"""The simulation's ground truth kept for benchmarks, in memory, written once at the end. No rclpy.

A benchmark of the running robot needs the true foot contacts to the millisecond (detection delay)
and the body's path (distance). Publishing them at 1 kHz over DDS loads the very process that is
being measured (in the composed robot it cost a third of the controller's cadence), so the bus
master keeps one row per millisecond of physics here and writes them as ``.npz`` (array ``truth``)
when it closes: wall time, simulated time, body x, y, z, and the six feet in contact (0/1) in the
physics step that ended then (:meth:`~hexapod_sim.physics.plant.HexapodSim.feet_touching_last_step`, the
contacts MuJoCo found for that step: no collision pass per row, which had lengthened the emulated
servos' replies by ~75 us in the real-time benchmarks).
"""
from __future__ import annotations

import math
import os
import time

import numpy as np

from hexapod_sim.physics.plant import SimError

TRUTH_PERIOD_S = 0.001       # one row per millisecond of physics
TRUTH_COLUMNS = ('wall_s', 'sim_s', 'x_m', 'y_m', 'z_m', *(f'contact_leg{i}' for i in range(1, 7)))


class TruthLog:
    """Rows of :data:`TRUTH_COLUMNS`, at most one per ``period_s`` of simulated time."""

    def __init__(self, path: str, period_s: float = TRUTH_PERIOD_S, clock=time.time):
        directory = os.path.dirname(os.path.abspath(path))
        if not os.path.isdir(directory):
            raise SimError(f'truth file {path}: directory {directory} does not exist')
        if not path.endswith('.npz'):
            raise SimError(f'truth file {path}: must end in .npz')
        self.path = path
        self.period_s = float(period_s)
        self.clock = clock
        self.rows: list[tuple] = []
        self._last_t = -math.inf

    def sample(self, sim) -> None:
        """Add a row for ``sim`` (a :class:`~hexapod_sim.physics.plant.HexapodSim`) if one is due."""
        now = sim.now()
        if now - self._last_t < self.period_s - 1e-9:
            return
        self._last_t = now
        pos, _ = sim.body_pose()
        self.rows.append((self.clock(), now, *pos, *sim.feet_touching_last_step()))

    def save(self) -> None:
        """Write the rows (atomically: a reader never sees half a file)."""
        tmp = f'{self.path}.part.npz'
        np.savez(tmp, truth=np.array(self.rows, dtype=float).reshape(-1, len(TRUTH_COLUMNS)))
        os.replace(tmp, self.path)


def load_truth(path: str) -> np.ndarray:
    """The rows a :class:`TruthLog` wrote, as an N x 11 array; one line naming what is wrong otherwise."""
    try:
        truth = np.load(path)['truth']
    except (OSError, KeyError, ValueError) as exc:
        raise SimError(f'truth file {path}: cannot be read ({exc})') from None
    if truth.ndim != 2 or truth.shape[1] != len(TRUTH_COLUMNS):
        raise SimError(f'truth file {path}: expected N x {len(TRUTH_COLUMNS)} rows, got shape {truth.shape}')
    return truth
