"""Gaits as data (paper Sec. 3): which legs swing together, in which order. Pure Python.

A gait is a cyclic sequence of *groups*; the legs of one group swing simultaneously (Algorithm 1
with L = group size) while all other legs support the body. The schedule is a pure function of an
integer phase index, so "three feet down at every tick" is a one-line check.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Mapping

import yaml

from hexapod_model.description import LEGS
from hexapod_model.param_schema import param
from hexapod_model.yaml_files import source_path, yaml_problem

# stride of a gait whose definition gives none [m] (reach: about 11 cm). A 10 cm stride stalled the
# real-time ROS graph at the first blocks of the mockup (docs/architecture.md); 9 cm is what tetrapod
# needs for the paper's speed at t_des = 1 s.
DEFAULT_STRIDE_M = 0.09
# largest yaw per cycle of a gait whose definition gives none [rad]
DEFAULT_TURN_RAD = 0.25


class GaitError(ValueError):
    """A gait definition is malformed (the message names the gait and the problem)."""


@dataclass(frozen=True)
class Gait:
    name: str
    groups: tuple[tuple[int, ...], ...]
    # the gait's stride: longest foothold displacement per cycle [m] with which it keeps its support
    # (LocomotionParams.max_stride_m, when set, replaces it)
    max_stride_m: float = DEFAULT_STRIDE_M
    # the gait's largest yaw per cycle [rad] (LocomotionParams.max_turn_rad, when set, replaces it)
    max_turn_rad: float = DEFAULT_TURN_RAD

    def __post_init__(self):
        for key in ('max_stride_m', 'max_turn_rad'):
            v = getattr(self, key)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise GaitError(f'gait {self.name!r}: {key} must be a finite positive number, got {v!r}')
        flat = [leg for g in self.groups for leg in g]
        if not self.groups or any(not g for g in self.groups):
            raise GaitError(f'gait {self.name!r}: needs at least one non-empty group')
        if sorted(flat) != list(LEGS):
            raise GaitError(f'gait {self.name!r}: every leg 1..6 must appear exactly once, got {flat}')

    @property
    def n_phases(self) -> int:
        return len(self.groups)

    def swing_legs(self, phase: int) -> tuple[int, ...]:
        """Legs swinging during phase ``phase`` (any integer; the gait is cyclic)."""
        return self.groups[phase % self.n_phases]

    def stance_legs(self, phase: int) -> tuple[int, ...]:
        swing = set(self.swing_legs(phase))
        return tuple(leg for leg in LEGS if leg not in swing)

    def phase_offsets(self) -> dict[int, float]:
        """Phase offset of each leg in [0, 1): the start of its swing within the cycle."""
        return {leg: i / self.n_phases for i, g in enumerate(self.groups) for leg in g}

    @property
    def min_support(self) -> int:
        return 6 - max(len(g) for g in self.groups)


def gaits_from_mapping(data: Mapping) -> dict[str, Gait]:
    if not isinstance(data, Mapping):
        raise GaitError('expected a mapping name -> {groups: [[legs...], ...]}')
    out = {}
    for name, spec in data.items():
        if not isinstance(spec, Mapping) or 'groups' not in spec:
            raise GaitError(f'gait {name!r}: expected a mapping with key "groups"')
        try:
            groups = tuple(tuple(int(x) for x in g) for g in spec['groups'])
        except (TypeError, ValueError):
            raise GaitError(f'gait {name!r}: groups must be lists of leg numbers, got {spec["groups"]!r}') from None
        limits = {'max_stride_m': DEFAULT_STRIDE_M, 'max_turn_rad': DEFAULT_TURN_RAD}
        for key in limits:
            v = spec.get(key)
            if v is not None and (isinstance(v, bool) or not isinstance(v, (int, float))):
                raise GaitError(f'gait {name!r}: {key} must be a number, got {v!r}')
            limits[key] = limits[key] if v is None else float(v)
        out[str(name)] = Gait(str(name), groups, **limits)
    return out


def load_gaits(path: str | Path | None = None) -> dict[str, Gait]:
    """Gaits from a YAML file (default: the packaged ``gaits.yaml``)."""
    p = source_path(path if path else str(resources.files('hexapod_locomotion').joinpath('data/gaits.yaml')))
    try:
        data = yaml.safe_load(p.read_text())
    except OSError as exc:
        raise GaitError(f'{p}: cannot read: {exc.strerror or exc}') from None
    except yaml.YAMLError as exc:
        raise GaitError(f'{p}: not valid YAML: {yaml_problem(exc)}') from None
    try:
        return gaits_from_mapping(data)
    except GaitError as exc:
        raise GaitError(f'{p}: {exc}') from None


def get_gait(name: str, path: str | Path | None = None) -> Gait:
    gaits = load_gaits(path)
    if name not in gaits:
        raise GaitError(f'unknown gait {name!r}; known: {sorted(gaits)}')
    return gaits[name]


@dataclass(frozen=True)
class GaitChoice:
    """Which gait walks: locomotion_node's parameter and a trial's field (declared once here)."""

    gait: str = param('tripod', 'gait (gaits.yaml)', choices=tuple(load_gaits()))
