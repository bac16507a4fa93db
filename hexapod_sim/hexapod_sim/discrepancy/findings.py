"""What an analysis finds: the effects it names, each joint's held-out fit, and what no candidate explains.

The analysis (:func:`~.analysis.analyse`) makes them on the swings, and the whole walk
(:mod:`.whole_walk_search`) adds to them and clears them; the report writes them out.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from hexapod_model.description import Effect
from hexapod_model.joints import Joint


@dataclass(frozen=True)
class JointFit:
    heldout_rmse_ticks_before: float
    heldout_rmse_ticks_after: float
    n_heldout: int


@dataclass(frozen=True)
class PhaseFit:
    n_reads: int
    rmse_ticks_before: float
    rmse_ticks_after: float


@dataclass(frozen=True)
class FoundEffect:
    effect: Effect
    scope: str                       # 'leg 3 tibia', 'leg 2', 'the whole robot'
    condition: str                   # where it shows (locate.CONDITIONS)
    heldout_rmse_ticks_before: float  # on the effect's joints, final model without this effect
    heldout_rmse_ticks_after: float   # final model


UNEXPLAINED_TICKS = 0.6     # held-out RMS error [ticks] above which a joint's mismatch is reported as unexplained
# a list effect on one joint that leaves it above this [ticks] held out may stand for a dictionary term
# there (an angle-periodic friction fitted as Coulomb friction left 0.53): the terms are tried in its place
DOUBTFUL_TICKS = 0.5


@dataclass(frozen=True)
class Unexplained:
    """A mismatch no candidate explains: joints, where it shows, its held-out RMS error [ticks] with the
    named effects in place, and the nearest candidate that was tried and not named (None: none passed)."""

    joints: tuple[Joint, ...]
    condition: str
    heldout_rmse_ticks: float
    nearest: Effect | None = None
    nearest_rmse_ticks: float = math.nan     # held-out RMS error on these joints with the nearest candidate


__all__ = ['FoundEffect', 'JointFit', 'PhaseFit', 'UNEXPLAINED_TICKS', 'Unexplained']
