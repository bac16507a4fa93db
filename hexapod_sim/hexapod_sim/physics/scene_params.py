"""The scene a simulation is built on: terrain, its seed and where the robot stands. Declared once
(:mod:`hexapod_model.param_schema`): sim_node's parameters and a trial's fields
(:class:`hexapod_locomotion.trials.trial_config.TrialConfig`) are derived from it. No MuJoCo import."""
from __future__ import annotations

from dataclasses import dataclass

from hexapod_model.param_schema import param
from hexapod_sim.physics.terrain import all_terrains


@dataclass(frozen=True)
class SceneParams:
    terrain: str = param('flat', 'terrain', choices=tuple(all_terrains()))
    seed: int = param(0, 'seed of the random terrains (blocks, rough, mockup)', min=0)
    start_x_m: float = param(0.0, 'start position of the trunk along x [m]')
    start_y_m: float = param(0.0, 'start position of the trunk along y [m]')
