"""The checks of a soak run (``hexapod soak``), as plain functions over what the run recorded. No rclpy.

Inputs are records, not live objects: diagnostics statuses as dicts (``t`` receive time, ``name``,
``level``, ``message``, ``values``), the emulator's fault events (start/end wall times), the
control periods measured from ``/ground_detection``, per-process RSS samples, the positions the
driver published (from the bag) and the positions the emulated servos reported.
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass, field

import numpy as np

GRACE_S = 3.0                     # a fault must show on /diagnostics within this long after it ends
_ID = re.compile(r'\(id (\d+)\)$')
_NONE = np.zeros(0)


@dataclass
class Check:
    name: str
    ok: bool
    detail: str


@dataclass
class FaultVerdict:
    fault: int
    text: str
    start: float
    end: float
    seen: bool | None                 # None: the fault could not be observed (see judge_faults)
    recovered: bool | None            # None: the policy does not expect a recovery
    notes: list[str] = field(default_factory=list)


def servo_id(status: dict) -> int | None:
    m = _ID.search(status['name'])
    return int(m.group(1)) if m else None


def _servo(statuses, sid):
    return [s for s in statuses if servo_id(s) == sid]


def _bus(statuses):
    return [s for s in statuses if s['name'].endswith(': bus')]


def _between(statuses, t0, t1):
    return [s for s in statuses if t0 <= s['t'] <= t1]


def _value(s: dict, key: str) -> str:
    return s['values'].get(key, '')


def judge_faults(faults: list[dict], statuses: list[dict], all_ids, t_end: float, fault_policy: str,
                 asked: dict[int, np.ndarray] | None = None,
                 corrupted: dict[int, np.ndarray] | None = None) -> list[FaultVerdict]:
    """Per injected fault (``{'fault', 'kind', 'ids', 'value', 'duration_s', 'start', 'end'}``, wall
    times): was it reported on /diagnostics while it lasted (or within :data:`GRACE_S`), and did the
    driver report the recovery afterwards (before ``t_end``) where the policy promises one?

    ``asked``: {servo id: wall times of the requests the servo did not answer}; ``corrupted``: {servo id:
    wall times of the requests it answered with a broken checksum}. A fault that touched no request
    cannot be noticed, and ``seen`` is None then, not False: a servo silent while the driver sent it
    nothing (the controller reading only the swinging femurs through a whole swing-down), or replies
    dropped or corrupted at random where none of the few requests of the fault's seconds drew the fault
    (9 reads at p = 0.2: 13 %)."""

    def untouched(times: dict | None, ids, t0, t1) -> bool:
        return times is not None and not any(np.any((times.get(i, _NONE) >= t0) & (times.get(i, _NONE) <= t1))
                                             for i in ids)

    out = []
    for f in faults:
        kind, ids = f['kind'], list(f['ids']) or list(all_ids)
        t0, t1 = f['start'], f.get('end', math.inf)
        during = _between(statuses, t0, min(t1, t_end) + GRACE_S)
        after = _between(statuses, t1, t_end) if math.isfinite(t1) else []
        text = f"{kind} {f['ids'] or 'all'} {f.get('value', '')} {f['duration_s']:.1f} s"
        rec: bool | None
        if kind in ('drop', 'corrupt'):
            seen = any(int(_value(s, 'failed_reads') or 0) > 0 for s in _bus(during))
            if not seen and untouched(asked if kind == 'drop' else corrupted, ids, t0, t1):
                seen = None           # no reply was dropped (corrupted): nothing to report
            rec = all(any(_value(s, 'responding') == 'true' for s in _servo(after, i)) for i in ids)
        elif kind == 'overheat':
            seen = all(any('overheating' in _value(s, 'error_bits') for s in _servo(during, i)) for i in ids)
            if fault_policy == 'recover':
                rec = all(any('overheating' not in _value(s, 'error_bits') and _value(s, 'torque_limit') == '100%'
                              for s in _servo(after, i)) for i in ids)
            else:
                rec = None            # limp: the joint stays out until the driver restarts
        elif kind == 'voltage':
            seen = any('input voltage' in _value(s, 'error_bits') for s in during)
            rec = all(any('input voltage' not in _value(s, 'error_bits') for s in _servo(after, i)) for i in ids)
        elif kind == 'silent':
            seen = all(any(_value(s, 'responding') == 'false' for s in _servo(during, i)) for i in ids)
            if not seen and untouched(asked, ids, t0, t1):
                seen = None           # no request reached the servo while it was silent: nothing to report
            rec = all(any(_value(s, 'responding') == 'true' for s in _servo(after, i)) for i in ids)
        elif kind == 'port':
            seen = any('port lost' in s['message'] for s in _bus(during))
            rec = any(int(_value(s, 'reads') or 0) > 0 and 'port lost' not in s['message'] for s in _bus(after))
        else:
            raise ValueError(f'unknown fault kind {kind!r}')
        if not math.isfinite(t1):
            rec = None                # still active when the run ended
        out.append(FaultVerdict(f['fault'], text, t0, t1, seen, rec))
    return out


def windows(t: np.ndarray, period: np.ndarray, t0: float, window_s: float) -> list[tuple[float, int, float, float]]:
    """(window start [s from t0], samples, median, p99) of ``period`` per ``window_s`` of ``t``."""
    t, period = np.asarray(t, float), np.asarray(period, float)
    if not len(t):
        return []
    k = np.floor((t - t0) / window_s).astype(int)
    out = []
    for w in range(int(k.max()) + 1):
        sel = period[k == w]
        if len(sel):
            out.append((w * window_s, len(sel), float(np.median(sel)), float(np.percentile(sel, 99))))
        else:
            out.append((w * window_s, 0, math.nan, math.nan))
    return out


def control_periods(reads: list[tuple[int, float, float]]) -> tuple[np.ndarray, np.ndarray]:
    """Control periods from ``/ground_detection`` reads (leg, swing start, read stamp): the time between
    consecutive reads of one leg in one swing-down (t_con). Returns (stamps, periods)."""
    by: dict[tuple[int, float], list[float]] = {}
    for leg, start, stamp in reads:
        by.setdefault((leg, round(start, 6)), []).append(stamp)
    ts, ps = [], []
    for stamps in by.values():
        s = np.sort(np.asarray(stamps))
        if len(s) > 1:
            ts.append(s[1:])
            ps.append(np.diff(s))
    if not ts:
        return np.zeros(0), np.zeros(0)
    t, p = np.concatenate(ts), np.concatenate(ps)
    order = np.argsort(t)
    return t[order], p[order]


def drift(first: tuple, last: tuple, tolerance: float) -> Check:
    """The last window's median and p99 within ``tolerance`` (fraction) of the first window's."""
    _, n0, med0, p0 = first
    _, n1, med1, p1 = last
    if not (n0 and n1):
        return Check('control period drift', False, f'no control periods in the first or last window ({n0}, {n1})')
    dm, dp = med1 / med0 - 1.0, p1 / p0 - 1.0
    ok = abs(dm) <= tolerance and abs(dp) <= tolerance
    return Check('control period drift', ok, f'median {med0 * 1e3:.2f} -> {med1 * 1e3:.2f} ms ({dm:+.1%}), '
                 f'p99 {p0 * 1e3:.2f} -> {p1 * 1e3:.2f} ms ({dp:+.1%}); limit {tolerance:.0%}')


def rss_growth(samples: list[tuple[float, float]], after_s: float) -> tuple[float, float]:
    """(RSS at ``after_s`` of the run, largest growth over it later) in bytes; samples are (t, rss)."""
    later = [(t, r) for t, r in samples if t >= after_s]
    if not later:
        return math.nan, math.nan
    base = later[0][1]
    return base, max(r for _, r in later) - base


def invented_positions(published: dict[int, np.ndarray], reported: dict[int, np.ndarray]) -> tuple[int, list[str]]:
    """Positions published that no servo reported: per servo, the published ticks (in publication
    order) must be a subsequence of the ticks that servo sent (in order; replies the driver did not
    take, as corrupt or late, are skipped over). Returns (count, up to 5 descriptions)."""
    bad, examples = 0, []
    for sid, pub in published.items():
        rep = np.asarray(reported.get(sid, np.zeros(0)))
        order = np.argsort(rep, kind='stable')          # positions of each tick value, ascending
        values = rep[order]
        j = 0
        for k, tick in enumerate(pub):
            lo, hi = np.searchsorted(values, tick, 'left'), np.searchsorted(values, tick, 'right')
            where = order[lo:hi]                         # the reports of this tick, in order
            n = np.searchsorted(where, j)
            if n == len(where):                          # not reported (from here on): counted, skipped
                bad += 1
                if len(examples) < 5:
                    examples.append(f'id {sid}: published tick {int(tick)} (message {k} of {len(pub)}) never '
                                    f'reported by the servo after its report {j} of {len(rep)}')
                continue
            j = int(where[n]) + 1
    return bad, examples
