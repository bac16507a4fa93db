"""The MuJoCo hexapod as a backend of the driver's bus emulator: ``bus_emulator --backend sim``.

Registered in setup.py under the entry-point group ``hexapod_driver.emulator_backends``
(:data:`hexapod_driver.emulator.BACKEND_GROUP`), so the emulator finds it when this package is
installed without the driver importing the sim. The emulated servos' horns are the joints of
:class:`hexapod_sim.physics.plant.HexapodSim`, driven through the driver's generic
:class:`~hexapod_driver.emulator.ServoBusBackend` adapter, in step with wall-clock time.
"""
from __future__ import annotations

import argparse

from hexapod_driver.emulator import ServoBusBackend
from hexapod_model.cli_common import output_file
from hexapod_model.description import Robot
from hexapod_sim.physics.truth_log import TruthLog


class TruthRecordingBackend(ServoBusBackend):
    """The adapter over a :class:`HexapodSim` that also keeps the truth per millisecond of physics
    (:class:`~hexapod_sim.physics.truth_log.TruthLog`) and writes it at exit: what a benchmark compares the
    driver's view with (the emulator is not a ROS node, so it publishes no truth)."""

    def __init__(self, sim, robot: Robot, truth: TruthLog, max_catch_up_s: float | None = None):
        super().__init__(sim, robot, max_catch_up_s)
        self.truth = truth

    def _catch_up(self, t: float) -> None:
        super()._catch_up(t)
        self.truth.sample(self.bus)

    def close(self) -> None:
        self.truth.save()


class SimBackend:
    """Plug-in object: ``help``, ``add_arguments(group)``, ``create(robot, args)``."""

    help = 'the MuJoCo hexapod (hexapod_sim.physics.plant.HexapodSim) moves them, in step with wall-clock time'

    @staticmethod
    def add_arguments(group) -> None:
        from hexapod_sim.physics.terrain import TERRAINS
        group.add_argument('--terrain', default='flat', choices=list(TERRAINS), help='sim backend: terrain name')
        group.add_argument('--terrain-seed', type=int, default=0, help='sim backend: seed of a random terrain')
        group.add_argument('--fixed-base', action='store_true', help='sim backend: trunk fixed in the air')
        group.add_argument('--max-catch-up-ms', type=float, default=2.0,
                           help='sim backend: at most this much physics is run before a reply (an overloaded '
                                'host answers from slightly older physics instead of after the driver\'s timeout)')
        group.add_argument('--truth-out', default=None, metavar='FILE.npz', type=output_file(('.npz',)),
                           help='sim backend: at exit, write body position and foot contacts per ms of physics '
                                '(wall and sim time) here (for benchmarks)')

    @staticmethod
    def create(robot: Robot, args: argparse.Namespace) -> ServoBusBackend:
        if not args.max_catch_up_ms > 0:
            raise SystemExit(f'bus_emulator: --max-catch-up-ms must be > 0, got {args.max_catch_up_ms}')
        from hexapod_sim.physics.plant import HexapodSim, SimError  # MuJoCo is imported only when this backend is chosen
        truth = None
        if args.truth_out is not None:
            try:
                truth = TruthLog(args.truth_out)   # checks the path before the physics is built
            except SimError as exc:
                raise SystemExit(f'bus_emulator: --truth-out: {exc}') from None
        sim = HexapodSim(robot, terrain=args.terrain, seed=args.terrain_seed, fixed_base=args.fixed_base)
        cap = args.max_catch_up_ms / 1000.0
        if truth is not None:
            return TruthRecordingBackend(sim, robot, truth, cap)
        return ServoBusBackend(sim, robot, cap)
