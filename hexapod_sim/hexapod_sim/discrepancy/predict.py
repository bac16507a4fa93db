"""Predictions of the free-leg replay for any set of effects, the fit / held-out split of the reads, and
what a recording can show at all.

:class:`Predictor` predicts the analysed reads for the nominal robot plus any effects, caching the rollouts
of each leg by the effects that change them; :func:`make_split` chooses which reads fit parameters and
which judge them (:mod:`.fit`); :func:`unobservable` finds the joints on which an effect at its typical
magnitude changes the prediction too little for any fit to pass the held-out test.
"""
from __future__ import annotations

import math
import threading
from collections import OrderedDict
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

from hexapod_model.description import Effect, Robot
from hexapod_model.joints import LEG_JOINTS, Joint
from hexapod_sim.discrepancy.effects import BY_NAME, Candidate
from hexapod_sim.discrepancy.simulate import Replay

ROUNDING_VAR = 1.0 / 12.0   # variance [tick^2] of rounding to whole ticks (uniform in +-0.5)
TIME_SHIFTS = ('readout_delay', 'goal_latency')     # predicted as a shift of the prediction (simulate.Replay.sample)

SINGLE_SWING_BLOCK_S = 0.1   # fit / held-out blocks within the only swing of a leg (walks)


@dataclass(frozen=True)
class Split:
    """Per joint: which analysed reads are for fitting and which are held out."""

    fit: dict
    hold: dict
    block_s: float


def make_split(replay: Replay, block_s: float = 2.0, skip_start_s: float = 0.3, by_segment: bool = False) -> Split:
    """Alternating time blocks of ``block_s``: even blocks fit, odd blocks held out.

    ``by_segment`` (walks): alternate free spans of each leg instead (its even swings fit, its odd
    swings held out), so every leg with two swings has both fitting and held-out reads however slow
    the gait (a pentapod leg swings every ~5 s: 2 s blocks left some joints with no held-out read);
    a leg with a single swing alternates blocks of ``SINGLE_SWING_BLOCK_S`` within it.
    Reads within ``skip_start_s`` of a segment start (initial state not yet forgotten) are in neither.
    """
    if not block_s > 0:
        raise ValueError(f'block_s must be > 0, got {block_s}')
    fit, hold = {}, {}
    for j in replay.joints:
        r = replay.reads[j]
        leg = j.leg
        starts = np.array([replay.segments[leg][i][0] * replay.dt for i in r.segment])
        ok = r.t_s >= starts + skip_start_s
        if by_segment and len(replay.segments[leg]) > 1:
            even = (r.segment % 2) == 0
        elif by_segment:            # a leg with one swing: alternate short blocks within it
            even = (np.floor(r.t_s / SINGLE_SWING_BLOCK_S).astype(np.int64) % 2) == 0
        else:
            even = (np.floor(r.t_s / block_s).astype(np.int64) % 2) == 0
        fit[j] = ok & even
        hold[j] = ok & ~even
    return Split(fit, hold, 0.0 if by_segment else block_s)


def effect_units(c: Candidate, joints) -> list[tuple[Joint, tuple[Joint, ...]]]:
    """The smallest sets of ``joints`` candidate ``c`` is put on, each with a key joint: single joints;
    a payload's legs; the servo law's whole robot (it is the same firmware on every servo)."""
    joints = tuple(joints)
    if c.servo_law:             # on a single joint a servo-law term is that joint's own effect
        return [(joints[0], joints)] if len(joints) > 1 else []
    if c.leg_only:
        return [(LEG_JOINTS[leg][0], tuple(j for j in LEG_JOINTS[leg] if j in joints))
                for leg in sorted({j.leg for j in joints})]
    return [(j, (j,)) for j in joints]


def affected_joints(effect: str, joints) -> set[Joint]:
    """Joints whose predictions an effect on ``joints`` changes."""
    out: set[Joint] = set()
    for j in joints:
        if effect in TIME_SHIFTS:
            out.add(j)
        elif effect == 'mass_error':
            out.update(LEG_JOINTS[j.leg])
        elif j.role == 'coxa':
            out.add(j)
        else:
            out.update((Joint(j.leg, 'femur'), Joint(j.leg, 'tibia')))
    return out


class Predictor:
    """Predictions for any set of effects, with a cache of rollouts keyed by the effects that matter."""

    def __init__(self, replay: Replay, base: Robot, workers: int = 2, cache_size: int = 96):
        self.rep = replay
        self.base = base
        self.cache: OrderedDict = OrderedDict()
        self.cache_size = cache_size
        self.pool = ThreadPoolExecutor(max_workers=workers) if workers > 1 else None
        self.lock = threading.Lock()       # the cache is shared by the worker threads
        self.n_rollouts = 0

    def close(self):
        if self.pool is not None:
            self.pool.shutdown()

    @staticmethod
    def _key(effects, leg: int, which: str):
        mine = {Joint(leg, 'coxa')} if which == 'coxa' else {Joint(leg, 'femur'), Joint(leg, 'tibia')}
        key = []
        for e in effects:
            if e.effect in TIME_SHIFTS:       # a shift of the prediction at the reads, not of the rollout
                continue
            if e.effect == 'mass_error':
                if any(j.leg == leg for j in e.joints):
                    key.append(('mass_error', 'leg', tuple(sorted(e.params.items()))))
                continue
            js = tuple(sorted(set(e.joints) & mine))
            if js:
                key.append((e.effect, js, tuple(sorted(e.params.items()))))
        return (leg, which, tuple(sorted(key)))

    def _rollouts(self, robot: Robot, effects, leg: int, which: str):
        key = self._key(effects, leg, which)
        with self.lock:
            hit = self.cache.get(key)
            if hit is not None:
                self.cache.move_to_end(key)
                return hit
        val = self.rep.rollout_segments(robot, leg, which)
        with self.lock:
            self.n_rollouts += 1
            self.cache[key] = val
            if len(self.cache) > self.cache_size:
                self.cache.popitem(last=False)
        return val

    def predict(self, effects, joints) -> dict[Joint, np.ndarray]:
        """Predicted ticks at the analysed reads of ``joints`` for the base robot plus ``effects``."""
        effects = tuple(effects)
        robot = self.base.with_effects(effects)
        want = [j for j in joints if j in self.rep.reads]
        jobs = []
        for leg in sorted({j.leg for j in want}):
            roles = {j.role for j in want if j.leg == leg}
            if roles & {'femur', 'tibia'}:
                jobs.append((leg, 'ft'))
            if 'coxa' in roles:
                jobs.append((leg, 'coxa'))
        if self.pool is not None and len(jobs) > 1:
            results = list(self.pool.map(lambda lw: self._rollouts(robot, effects, *lw), jobs))
        else:
            results = [self._rollouts(robot, effects, *lw) for lw in jobs]
        out = {}
        for (leg, which), per_seg in zip(jobs, results):
            cols = (('coxa', 0),) if which == 'coxa' else (('femur', 0), ('tibia', 1))
            for role, col in cols:
                j = Joint(leg, role)
                if j in want:
                    out[j] = self.rep.sample(robot, j, per_seg, col)
        return out


def least_confirmable_change(min_drop_ticks: float) -> float:
    """RMS change [ticks] of a prediction below which no fit can pass the held-out drop.

    The reads also carry tick rounding (variance :data:`ROUNDING_VAR`, independent of the motion), so
    even a fit that explains an effect exactly leaves RMS ``sigma = sqrt(ROUNDING_VAR)``: an effect that
    changes the prediction by RMS ``c`` raises the nominal residual to at most
    ``sqrt(sigma^2 + c^2)`` where nothing else is missing, and the drop reaches ``min_drop_ticks``
    only when ``c >= sqrt((sigma + min_drop_ticks)^2 - sigma^2)``: 0.33 tick on a walk, 0.14 on a stand.
    """
    sigma = math.sqrt(ROUNDING_VAR)
    return math.sqrt((sigma + min_drop_ticks) ** 2 - ROUNDING_VAR)


def can_confirm(change: tuple[float, float, int], min_drop_ticks: float, min_gain_ticks2: float,
                either: bool = False) -> bool:
    """Whether an effect whose prediction change is ``change`` (:func:`prediction_change`) could pass
    the held-out test at all: a large enough RMS change (:func:`least_confirmable_change`) on the
    fitting and on the held-out reads (``either``: on one of them, the more cautious answer), and on
    enough held-out reads that the squared error can fall by ``min_gain_ticks2`` (at most
    ``n_hold * c_hold^2``)."""
    fit_c, hold_c, n_hold = change
    least = least_confirmable_change(min_drop_ticks)
    big = (max if either else min)(fit_c, hold_c) >= least
    return big and n_hold * hold_c ** 2 >= min_gain_ticks2


def unobservable(pred: Predictor, split: Split, base_pred: dict, candidates, min_drop_ticks: float,
                 min_gain_ticks2: float) -> dict[str, tuple[Joint, ...]]:
    """Per candidate effect: the analysed joints on which this recording cannot show it.

    The effect at its typical magnitude (:mod:`.effects`) is put on one joint (a payload: on one
    leg) and the change of the prediction is measured on the analysed reads it touches. Where it
    is too small for any fit to pass the held-out test (:func:`can_confirm`: below the drop an
    accepted effect needs on top of tick rounding, or on too few held-out reads for the gain), no
    fit can be accepted there. So "cannot show" is a property of the recording's motion and length,
    computed, not guessed from its conditions.
    """
    rep = pred.rep
    out = {}
    for name in candidates:
        c = BY_NAME[name]
        units = [on for _key, on in effect_units(c, rep.joints)]
        blind = []
        for on in units:
            if on and not can_confirm(prediction_change(pred, split, base_pred, c.make(on, c.typical)),
                                      min_drop_ticks, min_gain_ticks2):
                blind.extend(j for j in on if not (name == 'mass_error' and j.role == 'coxa'))
        if blind:
            out[name] = tuple(blind)
    return out


def prediction_change(pred: Predictor, split: Split, base_pred: dict, effect: Effect) -> tuple[float, float, int]:
    """RMS change [ticks] of the prediction when ``effect`` is added, on the fitting and on the held-out
    reads of the joints it touches (0 where it touches no analysed read), and the number of those
    held-out reads."""
    aff = sorted(affected_joints(effect.effect, effect.joints) & set(pred.rep.joints))
    if not aff:
        return 0.0, 0.0, 0
    p = pred.predict((effect,), aff)
    out = []
    for masks in (split.fit, split.hold):
        d = np.concatenate([(p[j] - base_pred[j])[masks[j]] for j in aff])
        out.append(math.sqrt(float(d @ d) / len(d)) if len(d) else 0.0)
    return out[0], out[1], int(sum(np.count_nonzero(split.hold[j]) for j in aff))
