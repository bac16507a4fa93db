"""The namer's hypotheses (an effect on some joints, its fitted parameter and its held-out errors) and its
settings (:mod:`.fit`)."""
from __future__ import annotations

import math
from dataclasses import dataclass, field

from hexapod_model.description import Effect
from hexapod_model.joints import Joint
from hexapod_sim.discrepancy.effects import CANDIDATES, Candidate


@dataclass
class Hypothesis:
    candidate: Candidate
    joints: tuple[Joint, ...]
    screen_gain: float = 0.0
    screen_ratio: float = 1.0
    value: float = math.nan
    fit_sse_before: float = math.nan
    fit_sse_after: float = math.nan
    hold_sse_before: float = math.nan
    hold_sse_after: float = math.nan
    n_hold: int = 0
    affected: tuple[Joint, ...] = ()
    evals: int = 0
    # per affected joint: held-out (squared error before, after, number of reads)
    hold_by_joint: dict = field(default_factory=dict)

    @property
    def effect(self) -> Effect:
        return self.candidate.make(self.joints, self.value)

    @property
    def hold_rmse_before(self) -> float:
        return math.sqrt(self.hold_sse_before / max(self.n_hold, 1))

    @property
    def hold_rmse_after(self) -> float:
        return math.sqrt(self.hold_sse_after / max(self.n_hold, 1))

    @property
    def hold_gain(self) -> float:
        return self.hold_sse_before - self.hold_sse_after


@dataclass
class FitSettings:
    min_ratio: float = 1.15          # held-out RMS before/after on the effect's joints
    min_drop_ticks: float = 0.03     # and at least this absolute drop
    walk_min_drop_ticks: float = 0.15  # on a walk (fewer, shorter free spans: small dents are not effects)
    min_explained: float = 0.5       # and explain this share of the held-out variance above tick rounding
    # with every named effect in place, each must still explain this share of its joints' held-out excess
    # over rounding; below it, it is the nearest candidate to physics the library lacks: not named
    min_final_explained: float = 0.75
    # and lower the held-out squared error by this much [tick^2] in all: 120 reads' worth of rounding
    # variance, so a few held-out reads cannot confirm an effect alone (a 0.01 N m s/rad damping on
    # one coxa of a walk, 17 reads 0.52 -> 0.30 ticks: 3 tick^2; true effects on the walk bench: >= 62)
    min_gain_ticks2: float = 10.0
    parsimony: float = 0.95          # prefer a smaller scope reaching this share of the best gain
    max_effects: int = 4
    n_fit: int = 6                   # hypotheses fitted exactly per round
    min_screen_ratio: float = 1.02   # skip exact fits the linear screen gives no chance
    screen_floor_ticks: float = 0.4  # joints with a fitting residual below this need no explaining
    grid: int = 8
    feature_window_s: float = 0.25
    candidates: tuple[str, ...] = tuple(c.effect for c in CANDIDATES)
    dictionary: bool = True          # search the dictionary of physical terms where the candidates leave a mismatch
    log: list = field(default_factory=list)
