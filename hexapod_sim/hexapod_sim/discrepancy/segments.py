"""Which parts of a recording fit the free-leg model.

On a stand (fixed base, feet in the air) every leg hangs free for the whole recording. In a walk
the stance legs carry the body, so only the swing phases fit: a swing is recognised from the
commands alone as an upward femur motion (swing-up, at least ``min_lift_rad``) followed by the
downward motion that ends it (swing-down) when the goal holds still; the span analysed runs from
``settle_s`` after the lift starts (the foot has left the ground) to ``before_stop_s`` before the
swing-down stops (the ground detector stops the leg at contact, so the last moments may already
touch the ground).

``auto`` mode decides between the two from the data: outside its swing phases a stance leg is
pushed *above* the free-leg prediction by the body's weight, which a hanging leg never shows
(:func:`looks_like_walk`).
"""
from __future__ import annotations

import numpy as np

from hexapod_model.description import joint_name
from .recording import Recording, RecordingError


def parse_windows(texts) -> list[tuple[float, float]]:
    """``['2.5:10', '12:20']`` -> [(2.5, 10.0), (12.0, 20.0)] (seconds from the start of the bag)."""
    out = []
    for t in texts:
        try:
            a, b = (float(x) for x in str(t).split(':'))
        except ValueError:
            raise RecordingError(f'--time {t!r}: expected START:END in seconds, e.g. 2.5:10') from None
        if not (np.isfinite(a) and np.isfinite(b) and b > a >= 0):
            raise RecordingError(f'--time {t!r}: need 0 <= START < END')
        out.append((a, b))
    return sorted(out)


def swing_segments(rec: Recording, legs, min_lift_rad: float = 0.08, settle_s: float = 0.08,
                   before_stop_s: float = 0.1, hold_s: float = 0.15,
                   grid_s: float = 0.01) -> dict[int, list[tuple[float, float]]]:
    """Free-leg spans of every leg in a walk, from its femur commands (see the module docstring).

    A swing starts where the femur goal starts rising by at least ``min_lift_rad`` and ends at the
    last change of the goal after it has come down again, before the goal holds still for
    ``hold_s`` (the leg stands; the ground detector stopped it) or the next lift starts.
    """
    out: dict[int, list[tuple[float, float]]] = {}
    t_end = rec.duration_s
    t = np.arange(0.0, t_end + grid_s, grid_s)
    n_hold = max(int(round(hold_s / grid_s)), 1)
    for leg in legs:
        cmd = rec.commands.get(joint_name(leg, 'femur'))
        if cmd is None or len(cmd) < 2:
            out[leg] = []
            continue
        i = np.clip(np.searchsorted(cmd.t_s, t, side='right') - 1, 0, None)
        g = cmd.theta_rad[i]
        d = np.sign(np.where(np.abs(np.diff(g)) > 1e-6, np.diff(g), 0.0))
        n = len(d)
        spans = []
        k = 0
        while k < n:
            if d[k] <= 0 or (k > 0 and d[k - 1] > 0):
                k += 1
                continue
            a = k                                        # a rise starts
            while k < n and d[k] >= 0 and not np.all(d[k:k + n_hold] == 0):
                k += 1
            lift = g[k] - g[a]
            if lift < min_lift_rad:
                continue
            fell = False
            last_change = k
            while k < n:
                if d[k] < 0:
                    fell = True
                if d[k] != 0:
                    last_change = k
                if fell and np.all(d[k:k + n_hold] == 0):
                    break                                # the leg holds: it stands
                if fell and d[k] > 0 and g[min(k + n_hold, n)] - g[k] >= min_lift_rad:
                    break                                # the next lift starts
                k += 1
            if not fell:
                continue
            t_a, t_b = t[a] + settle_s, t[last_change + 1] - before_stop_s
            if t_b - t_a > 0.05:
                spans.append((float(t_a), float(t_b)))
        out[leg] = spans
    return out


def looks_like_walk(replay, residual: dict, swings: dict, load_ticks: float = 1.5, min_reads: int = 10) -> bool:
    """True if femurs are pushed up outside their swing phases: the stance legs carry the body.

    ``residual``: read - nominal free-leg prediction per joint (whole recording); ``swings``: the
    swing spans of :func:`swing_segments`. On a stand a femur fits the free-leg model as well
    outside its swings as inside (effects such as friction or play spread both ways); in a walk
    the body's weight pushes every stance femur above the prediction (median over the reads outside
    the swings at least ``load_ticks`` above the median inside). A walk needs this on two femurs
    (one if only one is read).
    """
    femurs = [j for j in replay.joints if j.endswith('_femur')]
    hits = 0
    for j in femurs:
        leg = int(j[3])
        spans = swings.get(leg) or []
        if not spans:
            continue
        t = replay.reads[j].t_s
        inside = np.zeros(len(t), dtype=bool)
        for a, b in spans:
            inside |= (t >= a) & (t <= b)
        if np.count_nonzero(inside) < min_reads or np.count_nonzero(~inside) < min_reads:
            continue
        r = residual[j]
        if np.median(r[~inside]) - np.median(r[inside]) > load_ticks:
            hits += 1
    return hits >= min(2, len(femurs)) and hits > 0
