"""The before/after figure (PNG, matplotlib Agg): per joint, recorded vs simulated position error,
the mismatch windows, and the residual before and after the fitted effects."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from hexapod_sim.discrepancy.analysis import Analysis


def pick_joints(a: Analysis, limit: int = 4) -> list:
    """Joints of the found effects first (most improved first), else the worst-fitting joints."""
    gain = {j: v.heldout_rmse_ticks_before - v.heldout_rmse_ticks_after for j, v in a.joints.items()}
    found = {j for f in a.effects for j in f.effect.joints if j in a.joints}
    order = sorted(found, key=lambda j: -gain[j])
    if len(order) < limit:
        rest = sorted((j for j in a.joints if j not in found), key=lambda j: -a.joints[j].heldout_rmse_ticks_before)
        order += rest[: limit - len(order)]
    return order[:limit]


def _mark_clipped(ax, t: np.ndarray, y: np.ndarray, color: str) -> None:
    """Values beyond the y limits: a triangle on the edge they leave by, and a count with the extreme
    in the corner, so a spike cut off by the zoom is never silently lost."""
    lo, hi = ax.get_ylim()
    above, below = y > hi, y < lo
    if np.any(above):
        ax.plot(t[above], np.full(np.count_nonzero(above), hi), '^', ms=4, color=color, clip_on=False)
    if np.any(below):
        ax.plot(t[below], np.full(np.count_nonzero(below), lo), 'v', ms=4, color=color, clip_on=False)
    n = int(np.count_nonzero(above | below))
    if n:
        ext = y[above | below][np.argmax(np.abs(y[above | below]))]
        ax.text(0.005, 0.97, f'{n} read(s) beyond the axis (triangles; extreme {ext:+.0f} ticks)',
                transform=ax.transAxes, va='top', fontsize=7, color=color)


def _runs(t: np.ndarray, mask: np.ndarray) -> list[tuple[float, float]]:
    """(first, last) time of each run of consecutive True in ``mask``."""
    m = np.concatenate([[False], np.asarray(mask, bool), [False]])
    edges = np.flatnonzero(np.diff(m.astype(np.int8)))
    return [(float(t[a]), float(t[b - 1])) for a, b in zip(edges[::2], edges[1::2])]


def _legend(ax) -> None:
    """Beside the axes, never over the data."""
    ax.legend(loc='upper left', bbox_to_anchor=(1.005, 1.0), fontsize=7, borderaxespad=0.0)


def save_plot(a: Analysis, path: str | Path, joints=None) -> Path:
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    joints = list(joints) if joints else pick_joints(a)
    fig, axes = plt.subplots(2 * len(joints), 1, figsize=(14, 3.2 * len(joints)), sharex=True, squeeze=False,
                             layout='constrained')
    axes = axes[:, 0]
    rep = a.replay
    for i, j in enumerate(joints):
        r = rep.reads[j]
        k = np.clip(np.floor(r.t_s / rep.dt + 1e-9).astype(int), 0, rep.n_periods - 1)
        goal = rep.goals[j][k]
        pred0 = r.tick - a.residual_before[j]
        pred1 = r.tick - a.residual_after[j]
        ax = axes[2 * i]
        ax.plot(r.t_s, goal - r.tick, '.', ms=2, color='k', label='recorded  (goal - read)')
        ax.plot(r.t_s, goal - pred0, '-', lw=0.7, color='tab:red', label='nominal model')
        if a.effects:
            ax.plot(r.t_s, goal - pred1, '-', lw=0.7, color='tab:blue', label='model + fitted effects')
        for m in a.mismatches:
            if m.joint == j:
                ax.axvspan(m.t_start, m.t_end, color='orange', alpha=0.25, lw=0)
        lo, hi = np.percentile(goal - r.tick, [1, 99])
        pad = max(0.3 * (hi - lo), 2.0)
        ax.set_ylim(lo - pad, hi + pad)
        _mark_clipped(ax, r.t_s, goal - r.tick, 'k')
        ax.set_ylabel(f'{j}\nerror [ticks]')
        _legend(ax)
        ax2 = axes[2 * i + 1]
        hold = a.split.hold[j]
        jf = a.joints[j]
        ax2.plot(r.t_s, a.residual_before[j], '.', ms=1.5, color='tab:red',
                 label=f'residual before (held-out RMS {jf.heldout_rmse_ticks_before:.2f})')
        if a.effects:
            ax2.plot(r.t_s, a.residual_after[j], '.', ms=1.5, color='tab:blue',
                     label=f'after (held-out RMS {jf.heldout_rmse_ticks_after:.2f})')
        ax2.axhspan(-0.5, 0.5, color='0.85', lw=0, label='tick rounding')
        for m in a.mismatches:
            if m.joint == j:
                ax2.axvspan(m.t_start, m.t_end, color='orange', alpha=0.25, lw=0)
        label = 'held-out reads (judged, not fitted)'
        for t0, t1 in _runs(r.t_s, hold):
            ax2.axvspan(t0, t1, color='tab:green', alpha=0.12, lw=0, label=label)
            label = None
        both = np.concatenate([a.residual_before[j], a.residual_after[j]])
        lo, hi = np.percentile(both, [0.5, 99.5])
        ax2.set_ylim(min(lo, -0.6) - 0.3, max(hi, 0.6) + 0.3)
        _mark_clipped(ax2, r.t_s, a.residual_before[j], 'tab:red')
        ax2.set_ylabel('read - model\n[ticks]')
        _legend(ax2)
    axes[-1].set_xlabel('time [s]   (orange: mismatch windows of the nominal replay; green bands: held-out reads)')
    title = '; '.join(f'{f.scope}: {f.effect.effect}' for f in a.effects) or 'no missing physics found'
    fig.suptitle(f'{Path(a.source).name}: {title}', fontsize=10)
    out = Path(path)
    fig.savefig(out, dpi=90)
    plt.close(fig)
    return out
