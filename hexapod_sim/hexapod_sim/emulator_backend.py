"""The MuJoCo hexapod as a backend of the driver's bus emulator: ``bus_emulator --backend sim``.

Registered in setup.py under the entry-point group ``hexapod_driver.emulator_backends``
(:data:`hexapod_driver.emulator.BACKEND_GROUP`), so the emulator finds it when this package is
installed without the driver importing the sim. The emulated servos' horns are the joints of
:class:`hexapod_sim.plant.HexapodSim`, driven through the driver's generic
:class:`~hexapod_driver.emulator.ServoBusBackend` adapter, in step with wall-clock time.
"""
from __future__ import annotations

import argparse
import math
import os
import time

import numpy as np

from hexapod_driver.emulator import ServoBusBackend
from hexapod_model.description import Robot

TRUTH_PERIOD_S = 0.001       # one truth row per millisecond of physics


class TruthRecordingBackend(ServoBusBackend):
    """The adapter over a :class:`HexapodSim` that also keeps (wall time, sim time, body x, y, z,
    six foot contacts) per millisecond of physics and writes them as .npz at exit: what a benchmark
    compares the driver's view with (the emulator is not a ROS node, so it publishes no truth)."""

    def __init__(self, sim, robot: Robot, path: str, max_catch_up_s: float | None = None):
        super().__init__(sim, robot, max_catch_up_s)
        self.path = path
        self.rows: list[tuple] = []
        self._truth_t = -math.inf

    def _catch_up(self, t: float, slices: int = 1) -> None:
        super()._catch_up(t, slices)
        now = self.bus.now()
        if now - self._truth_t >= TRUTH_PERIOD_S:
            self._truth_t = now
            pos, _ = self.bus.body_pose()
            self.rows.append((time.time(), now, *pos, *self.bus.foot_contacts().in_contact))

    def close(self) -> None:
        tmp = f'{self.path}.part.npz'
        np.savez(tmp, truth=np.array(self.rows, dtype=float).reshape(-1, 11))
        os.replace(tmp, self.path)


class SimBackend:
    """Plug-in object: ``help``, ``add_arguments(group)``, ``create(robot, args)``."""

    help = 'the MuJoCo hexapod (hexapod_sim.plant.HexapodSim) moves them, in step with wall-clock time'

    @staticmethod
    def add_arguments(group) -> None:
        from .terrain import TERRAINS
        group.add_argument('--terrain', default='flat', choices=list(TERRAINS), help='sim backend: terrain name')
        group.add_argument('--terrain-seed', type=int, default=0, help='sim backend: seed of a random terrain')
        group.add_argument('--fixed-base', action='store_true', help='sim backend: trunk fixed in the air')
        group.add_argument('--max-catch-up-ms', type=float, default=2.0,
                           help='sim backend: at most this much physics is run before a reply (an overloaded '
                                'host answers from slightly older physics instead of after the driver\'s timeout)')
        group.add_argument('--truth-out', default=None, metavar='FILE.npz',
                           help='sim backend: at exit, write body position and foot contacts per ms of physics '
                                '(wall and sim time) here (for benchmarks)')

    @staticmethod
    def create(robot: Robot, args: argparse.Namespace) -> ServoBusBackend:
        if not args.max_catch_up_ms > 0:
            raise SystemExit(f'bus_emulator: --max-catch-up-ms must be > 0, got {args.max_catch_up_ms}')
        if args.truth_out is not None and not os.path.isdir(os.path.dirname(os.path.abspath(args.truth_out))):
            raise SystemExit(f'bus_emulator: --truth-out: the directory of {args.truth_out} does not exist')
        from .plant import HexapodSim      # MuJoCo is imported only when this backend is chosen
        sim = HexapodSim(robot, terrain=args.terrain, seed=args.terrain_seed, fixed_base=args.fixed_base)
        cap = args.max_catch_up_ms / 1000.0
        if args.truth_out is not None:
            return TruthRecordingBackend(sim, robot, args.truth_out, cap)
        return ServoBusBackend(sim, robot, cap)
