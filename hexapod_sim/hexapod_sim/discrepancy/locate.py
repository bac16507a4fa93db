"""Step 2, locate: where (joint, time window) and in which motion condition the recording departs
from the prediction by more than tick quantization explains.

A servo reports the rounded position, so a perfect model leaves a residual ``recorded -
predicted`` uniform in [-0.5, 0.5] tick (RMS 0.29). A window whose residual RMS exceeds
``threshold_ticks`` (default 0.75: well beyond that, and beyond the small integration
differences between model and sim) is a mismatch. Each read also gets the motion condition it
was taken in, from the commanded goals and the nominal prediction:

``load_reversal``       the gravity torque on the joint changes sign within +-0.15 s
``direction_reversal``  the commanded motion changed direction within the last 0.15 s
``start_from_rest``     the goal started moving within the last 0.15 s after a hold of >= 0.2 s
``large_error``         goal and predicted position differ by more than 10 ticks
``high_speed``          predicted speed above 0.8 rad/s
``steady_hold``         goal within 2 ticks for at least 0.15 s and the joint (nearly) at rest (a walk's
                        swing-forward creeps its goal by a tick now and then: still a hold for the servo)
``gravity_load_high``   gravity torque above 60 % of the joint's maximum in the recording
``gravity_load_low``    gravity torque below 20 % of it (the coxa never carries gravity)
``moving``              none of the above
(conditions overlap; a mismatch window or a fitted effect is described by the most specific
condition that holds most of its excess error while being concentrated there, see
:func:`_most_telling`).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.ndimage import maximum_filter1d, minimum_filter1d

from hexapod_model.description import Robot
from hexapod_model.joints import JOINT_ROLES, Joint
from hexapod_model.servo import theta_to_tick, tick_to_theta
from hexapod_model.swing_model import LegModel
from hexapod_sim.discrepancy.simulate import Replay

CONDITIONS = ('load_reversal', 'direction_reversal', 'start_from_rest', 'large_error', 'high_speed',
              'steady_hold', 'gravity_load_high', 'gravity_load_low', 'moving')
CONDITION_WORDS = {
    'load_reversal': 'at load reversals', 'direction_reversal': 'at direction reversals',
    'start_from_rest': 'when starting from rest', 'large_error': 'at large position errors',
    'high_speed': 'at high speed', 'steady_hold': 'in steady holds',
    'gravity_load_high': 'under high gravity load', 'gravity_load_low': 'under low gravity load',
    'moving': 'during ordinary motion',
}

REVERSAL_WINDOW_S = 0.15
HOLD_S = 0.15
HOLD_GOAL_TICKS = 2.0     # goal range over HOLD_S that still counts as a hold
REST_BEFORE_S = 0.2
MOTION_WINDOW_S = 0.06
LARGE_ERROR_TICKS = 10.0
HIGH_SPEED_RAD_S = 0.8
HOLD_SPEED_RAD_S = 0.05


WINDOW_S = 0.12        # sliding window of the residual RMS [s]


@dataclass(frozen=True)
class Mismatch:
    joint: Joint
    t_start: float
    t_end: float
    condition: str
    rmse_ticks: float               # over the whole (merged) window
    peak_rmse_ticks: float = float('nan')   # the largest sliding-window RMS in it: what flagged it
    phase: str = ''          # walks: the gait phase holding most of the window's reads (segments.PHASES)


def _forward_fill_nonzero(d: np.ndarray) -> np.ndarray:
    idx = np.where(d != 0, np.arange(len(d)), -1)
    np.maximum.accumulate(idx, out=idx)
    out = np.where(idx >= 0, d[np.clip(idx, 0, None)], 0)
    return out


def _near_events(events: np.ndarray, n: int, before: int, after: int) -> np.ndarray:
    """Boolean mask of periods within [e - before, e + after] of any event index."""
    m = np.zeros(n + 1, dtype=np.int64)
    for e in events:
        m[max(e - before, 0)] += 1
        m[min(e + after + 1, n)] -= 1
    return np.cumsum(m)[:n] > 0


def period_conditions(replay: Replay, robot: Robot, joint: Joint, pred_traj: np.ndarray) -> np.ndarray:
    """Boolean matrix (period, condition) of the conditions (:data:`CONDITIONS`) ``joint`` is in.

    ``pred_traj``: nominal predicted joint angle [rad] per period (NaN outside the segments).
    """
    dt = replay.dt
    g = replay.goals[joint]
    n = len(g)
    s = robot.servo
    w = max(int(round(MOTION_WINDOW_S / dt)), 1)
    shifted = np.concatenate([np.full(min(w, n), g[0]), g[:max(n - w, 0)]])     # g delayed by w periods
    direction = np.sign(g - shifted)
    ff = _forward_fill_nonzero(direction)
    flips = np.nonzero((ff[1:] != ff[:-1]) & (ff[:-1] != 0) & (ff[1:] != 0))[0] + 1
    rev = _near_events(flips, n, 0, int(REVERSAL_WINDOW_S / dt))
    changed = np.concatenate([[False], g[1:] != g[:-1]])
    wh = max(int(round(HOLD_S / dt)), 1)
    # range of the goal over the last HOLD_S (origin shifts the window to end at the period itself)
    g_range = (maximum_filter1d(g, wh + 1, origin=wh // 2, mode='nearest')
               - minimum_filter1d(g, wh + 1, origin=wh // 2, mode='nearest'))
    hold = g_range <= HOLD_GOAL_TICKS
    # start from rest: first goal change after a hold of REST_BEFORE_S
    ch_idx = np.nonzero(changed)[0]
    starts = []
    prev = -10 ** 9
    for k in ch_idx:
        if (k - prev) * dt >= REST_BEFORE_S:
            starts.append(k)
        prev = k
    start = _near_events(np.array(starts, dtype=np.int64), n, 0, int(REVERSAL_WINDOW_S / dt))
    q = np.where(np.isfinite(pred_traj), pred_traj, tick_to_theta(g, s))
    pred_tick = theta_to_tick(q, s)
    large = np.abs(g - pred_tick) > LARGE_ERROR_TICKS
    speed = np.abs(np.gradient(q, dt))
    fast = speed > HIGH_SPEED_RAD_S
    hold &= speed < HOLD_SPEED_RAD_S
    leg, role = joint.leg, joint.role
    load_rev = np.zeros(n, dtype=bool)
    g_high = np.zeros(n, dtype=bool)
    g_low = np.ones(n, dtype=bool)
    if role in ('femur', 'tibia'):
        model = LegModel(robot, leg)
        other = Joint(leg, 'tibia' if role == 'femur' else 'femur')
        q_other = tick_to_theta(replay.goals[other], s)
        qq = np.stack([q, q_other] if role == 'femur' else [q_other, q], axis=1)
        col = 0 if role == 'femur' else 1
        grav = np.array([model.gravity_torque_nm(x)[col] for x in qq[::5]])
        grav = np.repeat(grav, 5)[:n]
        sign = np.sign(grav)
        flips_g = np.nonzero((sign[1:] != sign[:-1]) & (sign[:-1] != 0))[0] + 1
        half = int(REVERSAL_WINDOW_S / dt)
        load_rev = _near_events(flips_g, n, half, half)
        gmax = float(np.max(np.abs(grav))) if len(grav) else 0.0
        if gmax > 0:
            g_high = np.abs(grav) >= 0.6 * gmax
            g_low = np.abs(grav) <= 0.2 * gmax
    masks = np.zeros((n, len(CONDITIONS)), dtype=bool)
    for name, mask in (('load_reversal', load_rev), ('direction_reversal', rev), ('start_from_rest', start),
                       ('large_error', large), ('high_speed', fast), ('steady_hold', hold),
                       ('gravity_load_high', g_high), ('gravity_load_low', g_low)):
        masks[:, CONDITIONS.index(name)] = mask
    masks[:, CONDITIONS.index('moving')] = ~masks.any(axis=1)
    return masks


def read_conditions(replay: Replay, robot: Robot, trajectories) -> dict[Joint, np.ndarray]:
    """Condition matrix (read, condition) of every analysed read; ``trajectories``: leg -> (t, theta (n, 3))."""
    out = {}
    for j in replay.joints:
        _, th = trajectories[j.leg]
        cond = period_conditions(replay, robot, j, th[:, JOINT_ROLES.index(j.role)])
        k = np.clip(np.floor(replay.reads[j].t_s / replay.dt + 1e-9).astype(np.int64), 0, len(cond) - 1)
        out[j] = cond[k]
    return out


def mismatch_windows(replay: Replay, residuals: dict[Joint, np.ndarray], conditions: dict[Joint, np.ndarray],
                     threshold_ticks: float = 0.75, window_s: float = WINDOW_S, merge_gap_s: float = 0.25,
                     min_reads: int = 3) -> list[Mismatch]:
    """Time windows per joint whose residual RMS exceeds ``threshold_ticks`` (see module docstring)."""
    out: list[Mismatch] = []
    for j in replay.joints:
        t = replay.reads[j].t_s
        r = residuals[j]
        if len(t) < min_reads:
            continue
        c2 = np.concatenate([[0.0], np.cumsum(r * r)])
        lo = np.searchsorted(t, t - window_s / 2, side='left')
        hi = np.searchsorted(t, t + window_s / 2, side='right')
        cnt = hi - lo
        rms = np.sqrt((c2[hi] - c2[lo]) / np.maximum(cnt, 1))
        flag = (rms > threshold_ticks) & (cnt >= min_reads)
        if not np.any(flag):
            continue
        idx = np.nonzero(flag)[0]
        # grow each flagged read to its window, then merge runs closer than merge_gap_s
        starts = t[lo[idx]]
        ends = t[np.maximum(hi[idx] - 1, 0)]
        runs = []
        a, b = starts[0], ends[0]
        for s_, e_ in zip(starts[1:], ends[1:]):
            if s_ <= b + merge_gap_s:
                b = max(b, e_)
            else:
                runs.append((a, b))
                a, b = s_, e_
        runs.append((a, b))
        for a, b in runs:
            m = (t >= a) & (t <= b)
            if np.count_nonzero(m) < min_reads:
                continue
            rr = r[m]
            excess = np.maximum(rr * rr - 1.0 / 12.0, 0.0)
            in_run = flag & (t >= a) & (t <= b)
            out.append(Mismatch(j, float(a), float(b), _most_telling(conditions[j][m], excess),
                                float(np.sqrt(np.mean(rr * rr))), float(np.max(rms[in_run]))))
    return out


SPECIFICITY = ('load_reversal', 'direction_reversal', 'start_from_rest', 'steady_hold', 'high_speed', 'large_error',
               'gravity_load_high', 'gravity_load_low', 'moving')


def _most_telling(masks: np.ndarray, weight: np.ndarray, min_lift: float = 2.0, tie: float = 0.05) -> str:
    """The condition that best describes where ``weight`` (excess error) concentrates.

    Conditions overlap. A condition qualifies when the weight is concentrated in it (its *lift*,
    mean weight per read in the condition over the mean per read overall, is at least
    ``min_lift``); among those, the one holding the largest share of the total weight wins, the
    more specific (order of :data:`SPECIFICITY`) on a near tie.
    """
    total = float(weight.sum())
    if total <= 0 or len(weight) == 0:
        return 'moving'
    gain = weight @ masks
    count = masks.sum(axis=0)
    share = gain / total
    lift = np.where(count > 0, (gain / np.maximum(count, 1)) / (total / len(weight)), 0.0)
    ok = lift >= min_lift
    if not np.any(ok):
        ok = lift >= lift.max()
    best = float(share[ok].max())
    for name in SPECIFICITY:
        i = CONDITIONS.index(name)
        if ok[i] and share[i] >= best - tie:
            return name
    return 'moving'


def dominant_condition(joints, conditions, before, after) -> str:
    """Where replacing the ``before`` residuals by the ``after`` ones gained most per read."""
    masks, gains = [], []
    for j in joints:
        if j in before:
            masks.append(conditions[j])
            gains.append(np.maximum(before[j] ** 2 - after[j] ** 2, 0.0))
    if not masks:
        return 'moving'
    return _most_telling(np.concatenate(masks), np.concatenate(gains))


# The motion a candidate effect needs to show itself, in words for the report's "cannot show" lines
# (which joints cannot show it is computed: :func:`.predict.unobservable`).
REVEALED_BY = {
    'coulomb_friction': 'motion',
    'static_friction': 'a start from rest or a hold',
    'viscous_damping': 'fast motion',
    'backlash': 'a load reversal (on a coxa: a direction reversal)',
    'torque_saturation': 'a large position error',
    'compliance_deadband': 'a steady hold',
    'readout_delay': 'fast motion',
    'mass_error': 'a femur or tibia under changing gravity load',
    'punch': 'small position errors (a hold under load, the end of a move)',
    'motor_damping': 'fast motion',
    'goal_latency': 'goals that change quickly',
}
