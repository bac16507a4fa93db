"""Terrain classes a foot can feel, and mixed courses of them. Pure numpy, no MuJoCo import.

Five classes, each with seeded variations (the values drawn per seed are listed with each):

``flat``      hard flat floor; friction ``FLAT_FRICTION``.
``rough``     rough ground: a MuJoCo height field (:func:`hexapod_sim.physics.terrain_geoms.rough_field`), peak to
              peak ``ROUGH_AMPLITUDE_RANGE_M``, correlation length ``ROUGH_CORRELATION_RANGE_M``.
``blocks``    a field of 10 x 10 cm blocks (:func:`hexapod_sim.physics.terrain_geoms.block_field`), top heights up
              to ``BLOCKS_TOP_RANGE_M``, slopes up to ``BLOCKS_SLOPE_RANGE_RAD``.
``soft``      soft ground: compliant contact of the floor (MuJoCo ``solref`` time constant
              ``SOFT_TIMECONST_RANGE_S``, ``solimp`` ``SOFT_SOLIMP``): a loaded foot sinks in.
``slippery``  low friction ``SLIPPERY_FRICTION_RANGE``.

Terrains (names for :func:`hexapod_sim.physics.terrain.make_terrain`): ``class_<name>`` walks on one class
(rough and blocks begin at ``CLASS_START_X_M`` after a hard flat start pad); ``course`` is a mixed
course of ``COURSE_SEGMENTS`` segments along +x, ``COURSE_SEGMENT_M`` long, each of another class
than the one before (the seed draws the order and every segment's variation).

The ground is a row of slabs (boxes whose tops are at z = 0, each with the contact of its class)
over a floor plane lowered by ``SLAB_THICKNESS_M`` that no foot reaches; the height field and the
blocks lie on hard slabs. :func:`layout` gives the segments (x ranges and their class) of a terrain:
the labels of a walk come from it and the truth of the trunk's x, never from the controller.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from hexapod_sim.physics.terrain_geoms import GROUND_RGBA, Box, Contact, HeightField, Terrain, TerrainError, block_field, rough_field

CLASSES = ('flat', 'rough', 'blocks', 'soft', 'slippery')

# ----------------------------------------------------------------------------- nominal values [N]
SLAB_THICKNESS_M = 0.10
SLAB_HALF_WIDTH_M = 1.0
GROUND_START_X_M = -1.0             # the ground begins behind the robot ...
GROUND_END_X_M = 4.0                # ... and ends far beyond any walk of these trials
CLASS_START_X_M = 0.25              # class_rough / class_blocks: the class begins here (start pad before)
FIELD_HALF_WIDTH_M = 0.40           # y extent (+-) of block fields and height fields
CLASS_FIELD_END_X_M = 2.2           # end of a class terrain's blocks / height field (a 60 s tripod walk: 1.7 m)
COURSE_SEGMENTS = 3
COURSE_FIRST_END_X_M = 0.50         # the first course segment (the robot's start) ends here
COURSE_SEGMENT_M = 0.70             # the feet span 0.5-0.6 m along x: a segment holds the whole robot
TAPER_M = 0.05                      # a height field's ends ramp down to the slab over this length

FLAT_FRICTION = (0.8, 1.2)
ROUGH_AMPLITUDE_RANGE_M = (0.025, 0.045)
ROUGH_CORRELATION_RANGE_M = (0.05, 0.09)
BLOCKS_TOP_RANGE_M = (0.03, 0.06)
BLOCKS_SLOPE_RANGE_RAD = (math.radians(4.0), math.radians(10.0))
SOFT_TIMECONST_RANGE_S = (0.04, 0.08)
SOFT_SOLIMP = (0.0, 0.95, 0.02, 0.5, 2.0)
SOFT_FRICTION = (0.8, 1.1)
SLIPPERY_FRICTION_RANGE = (0.08, 0.2)

CLASS_RGBA = {'flat': GROUND_RGBA, 'rough': GROUND_RGBA, 'blocks': GROUND_RGBA,
              'soft': (0.36, 0.50, 0.30, 1.0), 'slippery': (0.70, 0.80, 0.90, 1.0)}


@dataclass(frozen=True)
class Segment:
    """One stretch of ground: x range [m], its class and the variation drawn for it."""

    x0_m: float
    x1_m: float
    label: str
    params: tuple[tuple[str, float], ...] = ()

    def param(self, name: str) -> float:
        return dict(self.params)[name]


def _draw(label: str, rng: np.random.Generator) -> tuple[tuple[str, float], ...]:
    """The seeded variation of one segment of class ``label``."""
    if label == 'flat':
        return (('friction', float(rng.uniform(*FLAT_FRICTION))),)
    if label == 'rough':
        return (('amplitude_m', float(rng.uniform(*ROUGH_AMPLITUDE_RANGE_M))),
                ('correlation_m', float(rng.uniform(*ROUGH_CORRELATION_RANGE_M))),
                ('field_seed', float(rng.integers(0, 2**31 - 1))))
    if label == 'blocks':
        return (('top_m', float(rng.uniform(*BLOCKS_TOP_RANGE_M))),
                ('slope_rad', float(rng.uniform(*BLOCKS_SLOPE_RANGE_RAD))),
                ('field_seed', float(rng.integers(0, 2**31 - 1))))
    if label == 'soft':
        return (('timeconst_s', float(rng.uniform(*SOFT_TIMECONST_RANGE_S))),
                ('friction', float(rng.uniform(*SOFT_FRICTION))))
    if label == 'slippery':
        return (('friction', float(rng.uniform(*SLIPPERY_FRICTION_RANGE))),)
    raise TerrainError(f'unknown terrain class {label!r}; known classes: {", ".join(CLASSES)}')


def layout(name: str, seed: int) -> tuple[Segment, ...]:
    """The segments of terrain ``name`` (``class_<class>`` or ``course``) for ``seed``, along +x."""
    rng = np.random.default_rng([seed, 0x7e77])
    if name.startswith('class_') and name[6:] in CLASSES:
        label = name[6:]
        if label in ('rough', 'blocks'):
            return (Segment(GROUND_START_X_M, CLASS_START_X_M, 'flat', (('friction', 1.0),)),
                    Segment(CLASS_START_X_M, GROUND_END_X_M, label, _draw(label, rng)))
        return (Segment(GROUND_START_X_M, GROUND_END_X_M, label, _draw(label, rng)),)
    if name == 'course':
        labels = [str(rng.choice(['flat', 'soft', 'slippery']))]
        while len(labels) < COURSE_SEGMENTS:
            # a course has one height field at most: rough only once
            options = [c for c in CLASSES if c != labels[-1] and not (c == 'rough' and 'rough' in labels)]
            labels.append(str(rng.choice(options)))
        edges = ([GROUND_START_X_M] + [COURSE_FIRST_END_X_M + k * COURSE_SEGMENT_M for k in range(COURSE_SEGMENTS - 1)]
                 + [GROUND_END_X_M])
        return tuple(Segment(edges[k], edges[k + 1], lab, _draw(lab, rng)) for k, lab in enumerate(labels))
    raise TerrainError(f'unknown terrain class terrain {name!r}; known: {", ".join(CLASS_TERRAINS)}')


def label_at(segments, x_m) -> np.ndarray:
    """Class label of the segment at each x (vectorised); the first / last segment beyond the ends."""
    x = np.atleast_1d(np.asarray(x_m, dtype=float))
    edges = np.array([s.x1_m for s in segments[:-1]])
    idx = np.searchsorted(edges, x, side='right')
    return np.array([segments[i].label for i in idx])


def _field_end(seg: Segment, segments) -> float:
    return min(seg.x1_m, CLASS_FIELD_END_X_M) if seg is segments[-1] and len(segments) <= 2 else seg.x1_m


def build(name: str, seed: int, segments) -> Terrain:
    """The terrain of ``segments``: slabs with their contact, a height field and block fields on top."""
    boxes, hfield = [], None
    half_t = SLAB_THICKNESS_M / 2
    for k, seg in enumerate(segments):
        if seg.label == 'soft':
            contact = Contact(seg.param('friction'), (seg.param('timeconst_s'), 1.0), SOFT_SOLIMP)
        elif seg.label in ('flat', 'slippery'):
            contact = Contact(seg.param('friction'))
        else:
            contact = Contact(1.0)
        boxes.append(_slab(f'slab_{k}', seg, contact, half_t))
        if seg.label == 'blocks':
            x1 = _field_end(seg, segments)
            boxes.extend(block_field(np.random.default_rng(int(seg.param('field_seed'))), (seg.x0_m, x1),
                                     half_width=FIELD_HALF_WIDTH_M, heights=(0.0, seg.param('top_m')),
                                     max_slope_rad=seg.param('slope_rad'), prefix=f'block{k}'))
        elif seg.label == 'rough':
            hfield = _rough_segment(seg, _field_end(seg, segments))
    return Terrain(name, seed, boxes=tuple(boxes), hfield=hfield, floor_z_m=-SLAB_THICKNESS_M)


def _slab(name: str, seg: Segment, contact: Contact, half_t: float):
    return Box(name, ((seg.x0_m + seg.x1_m) / 2, 0.0, -half_t), ((seg.x1_m - seg.x0_m) / 2, SLAB_HALF_WIDTH_M, half_t),
               rgba=CLASS_RGBA[seg.label], contact=contact)


def _rough_segment(seg: Segment, x1: float) -> HeightField:
    half = ((x1 - seg.x0_m) / 2, FIELD_HALF_WIDTH_M)
    f = rough_field(np.random.default_rng(int(seg.param('field_seed'))), half_size=half,
                    amplitude=seg.param('amplitude_m'), correlation=seg.param('correlation_m'), pad_half=-1.0)
    e = f.elevation_m
    xs = np.linspace(-half[0], half[0], e.shape[1])
    ys = np.linspace(-half[1], half[1], e.shape[0])
    taper = np.clip((half[0] - np.abs(xs)) / TAPER_M, 0.0, 1.0)[None, :] * \
        np.clip((half[1] - np.abs(ys)) / TAPER_M, 0.0, 1.0)[:, None]
    return HeightField('rough', ((seg.x0_m + x1) / 2, 0.0), half, e * taper, 0.0)


def _maker(name: str):
    def make(seed: int) -> Terrain:
        return build(name, seed, layout(name, seed))
    return make


CLASS_TERRAINS = {**{f'class_{c}': _maker(f'class_{c}') for c in CLASSES}, 'course': _maker('course')}
