"""Terrains of the paper's experimental mockup (Fig. 10) as MuJoCo geoms. Pure numpy, no MuJoCo import.

World frame: x forward (the walking direction), y left, z up, metres; the floor is ``z = 0`` and the
robot starts at the origin. Every terrain leaves a flat start pad around the origin.

Terrains (select by name, :func:`make_terrain`):

``flat``    the floor only.
``blocks``  a field of wooden blocks 10 x 10 cm (paper Fig. 10) with random top heights
            (``BLOCK_HEIGHT_RANGE_M``) and random slopes (tilt about x or y up to ``BLOCK_MAX_SLOPE_RAD``),
            ahead of the robot along +x.
``stairs``  wooden stairs with 4 cm steps (paper Fig. 10) going up along +x, then a landing.
``rough``   a seedable random height field (smoothed noise, ``ROUGH_AMPLITUDE_M`` peak to peak).
``mockup``  the combined course of Fig. 10 along +x: flat start, blocks, then stairs.

The terrain classes a foot can feel (hard, rough, blocks, soft, slippery) and mixed courses of them
are terrains too (``class_flat`` ... ``course``, :mod:`hexapod_sim.physics.terrain_classes`); they give
ground slabs their own contact (:class:`Contact`: friction, softness).

The parts (sizes, boxes, height fields, contacts) live in :mod:`hexapod_sim.physics.terrain_geoms`
and are re-exported here, so callers import every terrain name from this module.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from hexapod_sim.physics.terrain_classes import CLASS_TERRAINS
from hexapod_sim.physics.terrain_geoms import (
    BLOCK_FIELD_X_M,
    BLOCK_HEIGHT_RANGE_M,
    BLOCK_MAX_SLOPE_RAD,
    MOCKUP_BLOCKS_X_M,
    MOCKUP_COURSE_END_M,
    MOCKUP_STAIRS_X_M,
    STAIRS_START_X_M,
    STEP_COUNT,
    STEP_RISE_M,
    STEP_TREAD_M,
    Box,
    Contact,
    HeightField,
    Terrain,
    TerrainError,
    block_field,
    rough_field,
    stair_flight,
)

__all__ = [  # the terrain parts callers use, re-exported from terrain_geoms
    'BLOCK_FIELD_X_M', 'BLOCK_HEIGHT_RANGE_M', 'BLOCK_MAX_SLOPE_RAD', 'MOCKUP_BLOCKS_X_M', 'MOCKUP_COURSE_END_M',
    'MOCKUP_STAIRS_X_M', 'STAIRS_START_X_M', 'STEP_COUNT', 'STEP_RISE_M', 'STEP_TREAD_M', 'Box', 'Contact',
    'HeightField', 'Terrain', 'TerrainError', 'block_field', 'rough_field', 'stair_flight',
    'TERRAINS', 'all_terrains', 'make_terrain', 'Ground',
]


def _flat(seed: int) -> Terrain:
    return Terrain('flat', seed)


def _blocks(seed: int) -> Terrain:
    return Terrain('blocks', seed, boxes=block_field(np.random.default_rng(seed), BLOCK_FIELD_X_M))


def _stairs(seed: int) -> Terrain:
    return Terrain('stairs', seed, boxes=stair_flight(STAIRS_START_X_M))


def _rough(seed: int) -> Terrain:
    return Terrain('rough', seed, hfield=rough_field(np.random.default_rng(seed)))


def _mockup(seed: int) -> Terrain:
    rng = np.random.default_rng(seed)
    return Terrain('mockup', seed, boxes=block_field(rng, MOCKUP_BLOCKS_X_M) + stair_flight(MOCKUP_STAIRS_X_M))


TERRAINS = {'flat': _flat, 'blocks': _blocks, 'stairs': _stairs, 'rough': _rough, 'mockup': _mockup}


def all_terrains() -> dict:
    """Every terrain generator by name: :data:`TERRAINS` and the terrain classes and courses."""
    return {**TERRAINS, **CLASS_TERRAINS}


def make_terrain(name: str, seed: int = 0) -> Terrain:
    """The terrain called ``name`` (one of :func:`all_terrains`); ``seed`` drives the random ones."""
    known = all_terrains()
    if name not in known:
        raise TerrainError(f'unknown terrain {name!r}; known terrains: {", ".join(known)}')
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise TerrainError(f'terrain seed must be a non-negative integer, got {seed!r}')
    return known[name](int(seed))


@dataclass(frozen=True)
class Ground:
    """What a simulated robot walks on: a terrain of :data:`TERRAINS`, its seed, and the trunk's start
    position on it [m]. Its text is the ``/sim/scene`` message a recording carries
    (:data:`hexapod_model.contract.SIM_SCENE`), so the sim-vs-real tool replays a walk on its ground."""

    terrain: str = 'flat'
    seed: int = 0
    start_xy_m: tuple[float, float] = (0.0, 0.0)

    def describe(self) -> str:
        x, y = self.start_xy_m
        return f'{self.terrain} (seed {self.seed})' + ('' if (x, y) == (0.0, 0.0) else f' from x={x:g} y={y:g} m')

    def to_text(self) -> str:
        x, y = (float(v) for v in self.start_xy_m)
        return f'{{terrain: {self.terrain}, seed: {int(self.seed)}, start_xy_m: [{x!r}, {y!r}]}}'

    @classmethod
    def from_text(cls, text: str) -> 'Ground':
        """Parse :meth:`to_text`'s text; :class:`TerrainError` naming what is wrong."""
        import yaml
        try:
            d = yaml.safe_load(text)
            xy = d.get('start_xy_m', (0.0, 0.0))
            g = cls(str(d['terrain']), d.get('seed', 0), (float(xy[0]), float(xy[1])))
        except (yaml.YAMLError, AttributeError, KeyError, TypeError, ValueError, IndexError):
            raise TerrainError(f'not a scene description: {str(text)[:80]!r}') from None
        make_terrain(g.terrain, g.seed)          # a known terrain and a valid seed, or TerrainError
        if not all(math.isfinite(v) for v in g.start_xy_m):
            raise TerrainError(f'start position must be finite, got {g.start_xy_m}')
        return g
