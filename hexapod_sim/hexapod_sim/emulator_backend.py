"""The MuJoCo hexapod as a backend of the driver's bus emulator: ``bus_emulator --backend sim``.

Registered in setup.py under the entry-point group ``hexapod_driver.emulator_backends``
(:data:`hexapod_driver.emulator.BACKEND_GROUP`), so the emulator finds it when this package is
installed without the driver importing the sim. The emulated servos' horns are the joints of
:class:`hexapod_sim.plant.HexapodSim`, driven through the driver's generic
:class:`~hexapod_driver.emulator.ServoBusBackend` adapter, in step with wall-clock time.
"""
from __future__ import annotations

import argparse

from hexapod_driver.emulator import ServoBusBackend
from hexapod_model.description import Robot


class SimBackend:
    """Plug-in object: ``help``, ``add_arguments(group)``, ``create(robot, args)``."""

    help = 'the MuJoCo hexapod (hexapod_sim.plant.HexapodSim) moves them, in step with wall-clock time'

    @staticmethod
    def add_arguments(group) -> None:
        from .terrain import TERRAINS
        group.add_argument('--terrain', default='flat', choices=list(TERRAINS), help='sim backend: terrain name')
        group.add_argument('--fixed-base', action='store_true', help='sim backend: trunk fixed in the air')

    @staticmethod
    def create(robot: Robot, args: argparse.Namespace) -> ServoBusBackend:
        from .plant import HexapodSim      # MuJoCo is imported only when this backend is chosen
        return ServoBusBackend(HexapodSim(robot, terrain=args.terrain, fixed_base=args.fixed_base), robot)
