"""Reads and writes that cannot be physical, found before anything is fitted.

A real recording can hold a few samples that no servo produced: a clock step or a corrupt
stamp puts a read a second away from when it was taken, so its position lands far from its
neighbours; a corrupt sample reports a position outside the servo's range. One such read can
dominate a least-squares fit. They are found here, reported (how many, which joint, when, why)
and left out of the analysis, so they never decide it.

Checks, per joint and topic:

* ``stamp_jump``: the header stamp lies more than ``stamp_tol_s`` *after* its bag record (log)
  time beyond the recording's usual offset (the running median of stamp - record time): no message
  is recorded before it was stamped. A stamp *before* its record time is delivery latency (DDS
  queues messages under load) unless it exceeds ``max_latency_s``. Needs the record time; bags
  written with record time = stamp pass trivially.
* ``out_of_order``: in recording order, the stamp runs back by more than ``stamp_tol_s`` behind
  the previous message's stamp of the same joint and topic.
* ``out_of_range`` (reads): the position is outside the servo's tick range.
* ``speed`` (reads): the position is farther from most of its neighbours (``half_window`` on each
  side, in stamp order) than the servo can travel in the time between them: ``speed_factor``
  times the model's no-load speed (stall torque over the reflected damping of the description's
  servo) plus ``tol_ticks`` of rounding and sampling.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hexapod_model.description import ServoParams
from hexapod_model.joints import Joint
from hexapod_model.servo import theta_to_tick

KINDS = ('stamp_jump', 'out_of_order', 'out_of_range', 'speed', 'clock')    # clock: /imu on another clock (recording.screen_imu)


@dataclass(frozen=True)
class Glitch:
    """One left-out sample: ``topic`` 'read' or 'command', its joint, its stamp [s from the bag start]
    (``topic`` 'imu': the /imu series, no joint)."""

    topic: str
    joint: Joint | None
    t_s: float
    kind: str
    detail: str

    @property
    def joint_name(self) -> str:
        return '' if self.joint is None else str(self.joint)


@dataclass(frozen=True)
class GlitchSettings:
    stamp_tol_s: float = 0.1
    max_latency_s: float = 2.0
    offset_window: int = 25          # messages on each side for the running median offset
    speed_factor: float = 2.0
    tol_ticks: float = 3.0
    half_window: int = 4


def no_load_speed_rad_s(servo: ServoParams) -> float:
    """The model servo's top speed: full torque spent on its back-EMF damping."""
    return servo.stall_torque_nm / servo.reflected_damping_nms_per_rad


def _running_median(x: np.ndarray, half: int) -> np.ndarray:
    n = len(x)
    if n == 0:
        return x.copy()
    pad = np.pad(x, half, mode='edge')
    win = np.lib.stride_tricks.sliding_window_view(pad, 2 * half + 1)
    return np.median(win, axis=1)[:n]


def stamp_glitches(stamp: np.ndarray, log: np.ndarray, s: GlitchSettings) -> tuple[np.ndarray, list[str], list[str]]:
    """Mask of samples with an impossible stamp, in any order; with their kind and detail."""
    n = len(stamp)
    bad = np.zeros(n, dtype=bool)
    kinds = [''] * n
    details = [''] * n
    if n == 0:
        return bad, kinds, details
    order = np.argsort(log, kind='stable')
    st, lg = stamp[order], log[order]
    off = st - lg
    dev = off - _running_median(off, s.offset_window)
    jump = (dev > s.stamp_tol_s) | (dev < -s.max_latency_s)
    # out of order: the stamp runs back behind the latest good stamp before it
    prev_max = np.maximum.accumulate(np.where(jump, -np.inf, st))
    back = np.zeros(n, dtype=bool)
    back[1:] = st[1:] < prev_max[:-1] - s.stamp_tol_s
    for i in np.flatnonzero(jump | back):
        k = order[i]
        bad[k] = True
        if jump[i]:
            kinds[k] = 'stamp_jump'
            details[k] = f'stamp {dev[i]:+.3f} s off its record time'
        else:
            kinds[k] = 'out_of_order'
            details[k] = f'stamp {prev_max[i - 1] - st[i]:.3f} s before an earlier message\'s'
    return bad, kinds, details


def speed_glitches(t: np.ndarray, theta: np.ndarray, servo: ServoParams,
                   s: GlitchSettings) -> tuple[np.ndarray, list[str], list[str]]:
    """Mask of reads (sorted by stamp) that are out of range or unreachable from most neighbours."""
    n = len(t)
    kinds = [''] * n
    details = [''] * n
    tick = theta_to_tick(theta, servo)
    out = (tick < -0.5) | (tick > servo.max_tick + 0.5)
    for i in np.flatnonzero(out):
        kinds[i] = 'out_of_range'
        details[i] = f'position {tick[i]:.0f} ticks, outside the servo range 0-{servo.max_tick}'
    vmax = s.speed_factor * no_load_speed_rad_s(servo) / servo.rad_per_tick     # ticks/s
    ok_votes = np.zeros(n)
    n_votes = np.zeros(n)
    worst = np.zeros(n)
    for d in range(1, s.half_window + 1):
        if d >= n:
            break
        dt = np.abs(t[d:] - t[:-d])
        dq = np.abs(tick[d:] - tick[:-d])
        valid = ~(out[d:] | out[:-d])
        ok = dq <= vmax * dt + s.tol_ticks
        excess = np.where(valid, dq - vmax * dt, 0.0)
        for side in (slice(d, None), slice(None, -d)):     # the pair (i, i + d) votes for both reads
            n_votes[side] += valid
            ok_votes[side] += valid & ok
            worst[side] = np.maximum(worst[side], excess)
    speed = ~out & (n_votes > 0) & (ok_votes < 0.5 * n_votes)
    for i in np.flatnonzero(speed):
        kinds[i] = 'speed'
        details[i] = f'{worst[i]:.0f} ticks farther from its neighbours than the servo can move'
    return out | speed, kinds, details


def screen(rows: dict[Joint, np.ndarray], topic: str, servo: ServoParams | None,
           settings: GlitchSettings = GlitchSettings()) -> tuple[dict[Joint, np.ndarray], list[tuple]]:
    """Split ``{joint: array (N, 2 or 3)}`` (stamp, value[, record time]) into kept rows and glitches.

    Returns the kept ``(N', 2)`` rows sorted by stamp and ``[(joint, stamp, kind, detail)]``.
    Position checks run on reads only (``servo`` given).
    """
    kept: dict[Joint, np.ndarray] = {}
    found: list[tuple] = []
    for j, a in rows.items():
        a = np.asarray(a, dtype=float)
        if a.ndim != 2 or len(a) == 0:
            kept[j] = a.reshape(-1, 2) if a.size == 0 else a[:, :2]
            continue
        bad = np.zeros(len(a), dtype=bool)
        kinds = [''] * len(a)
        details = [''] * len(a)
        if a.shape[1] >= 3 and np.all(np.isfinite(a[:, 2])):
            bad, kinds, details = stamp_glitches(a[:, 0], a[:, 2], settings)
        for i in np.flatnonzero(bad):
            found.append((j, float(a[i, 0]), kinds[i], details[i]))
        b = a[~bad][:, :2]
        b = b[np.argsort(b[:, 0], kind='stable')]
        if servo is not None and len(b) and np.all(np.isfinite(b)):
            bad2, kinds2, details2 = speed_glitches(b[:, 0], b[:, 1], servo, settings)
            for i in np.flatnonzero(bad2):
                found.append((j, float(b[i, 0]), kinds2[i], details2[i]))
            b = b[~bad2]
        kept[j] = b
    return kept, found


def summary_line(glitches) -> str:
    """'3 glitched samples left out: 2 speed, 1 stamp_jump' (empty when none)."""
    if not glitches:
        return ''
    counts = {k: sum(1 for g in glitches if g.kind == k) for k in KINDS}
    parts = ', '.join(f'{v} {k.replace("_", " ")}' for k, v in counts.items() if v)
    return f'{len(glitches)} physically impossible sample(s) left out of the analysis ({parts})'
