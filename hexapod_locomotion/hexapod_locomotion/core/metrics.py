"""Performance indicators of the paper's Sec. 8, computed from time series. Pure numpy.

* Cost of transport, Eq. 18: ``CoT = P / (m g v)`` with ``v = ds/dt`` over ``dt = 10 s`` windows
  and the power averaged over the same windows (Sec. 8.3); for a walk the windows start at its first
  swing-down (:func:`walk_cost_of_transport`, used by the demo and by ``analyse`` alike).
* Stability, Fig. 11: per swing-down phase and leg, the variance of body pitch, roll and vertical
  acceleration from the IMU, sampled at 400 Hz while the legs swing down.
* Ground-detection quality (only measurable in simulation): delay from true contact to detection,
  premature stops (detected before any true contact), missed contacts (ground touched but the
  leg ran to theta_fin), command overshoot and femur torque at detection.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np


def roll_pitch_yaw(quat_wxyz) -> tuple[float, float, float]:
    """ZYX Euler angles [rad] of a unit quaternion (w, x, y, z)."""
    w, x, y, z = (float(v) for v in quat_wxyz)
    roll = math.atan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
    pitch = math.asin(max(-1.0, min(1.0, 2 * (w * y - z * x))))
    yaw = math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
    return roll, pitch, yaw


class MetricsError(ValueError):
    """Not enough data to compute an indicator (the message says which)."""


COT_WINDOW_S = 10.0          # Eq. 18's averaging window (Sec. 8.3): a walk needs one whole window


def windowed_speed_and_power(t_s, xy_m, t_power_s, power_w, window_s: float = 10.0, start_s: float | None = None):
    """Per-window speed [m/s] (displacement over the window / window) and mean power [W].

    The windows follow each other from ``start_s`` (default: the first pose sample) while a whole
    window fits before the last pose sample. A power sample is the mean over the period before its
    stamp (:class:`hexapod_sim.physics.plant.PowerMeter`), so a window ``(start, end]`` averages the samples
    stamped in it."""
    t = np.asarray(t_s, dtype=float)
    xy = np.asarray(xy_m, dtype=float)
    tp = np.asarray(t_power_s, dtype=float)
    p = np.asarray(power_w, dtype=float)
    if len(t) < 2 or len(tp) < 2:
        raise MetricsError('need at least two pose and two power samples')
    start = t[0] if start_s is None else float(start_s)
    if t[-1] - start < window_s - 1e-9:
        raise MetricsError(f'the walk lasted {max(t[-1] - start, 0.0):.1f} s from its first swing-down, shorter than '
                           f'one {window_s:g} s window')
    speeds, powers = [], []
    while start + window_s <= t[-1] + 1e-9:
        end = start + window_s
        a = np.array([np.interp(start, t, xy[:, i]) for i in range(xy.shape[1])])
        b = np.array([np.interp(end, t, xy[:, i]) for i in range(xy.shape[1])])
        speeds.append(np.linalg.norm(b - a) / window_s)
        sel = (tp > start + 1e-9) & (tp <= end + 1e-9)
        powers.append(p[sel].mean() if sel.any() else np.interp(start + window_s / 2, tp, p))
        start = end
    return np.array(speeds), np.array(powers)


def cost_of_transport(t_s, xy_m, t_power_s, power_w, mass_kg: float, gravity_mps2: float = 9.81,
                      window_s: float = 10.0, start_s: float | None = None) -> dict:
    """Eq. 18 over 10 s windows; returns the mean CoT, speed and power, and the per-window values."""
    v, p = windowed_speed_and_power(t_s, xy_m, t_power_s, power_w, window_s, start_s)
    with np.errstate(divide='ignore'):
        cot = p / (mass_kg * gravity_mps2 * v)
    return {'cot': float(np.mean(cot)), 'speed_mps': float(np.mean(v)), 'power_w': float(np.mean(p)),
            'windows': len(v), 'cot_per_window': cot.tolist(), 'speed_per_window': v.tolist()}


def walk_cost_of_transport(pose_t_s, pose_xy_m, power_t_s, power_w, first_swing_down_s: float, mass_kg: float,
                           gravity_mps2: float) -> dict:
    """Eq. 18 of a recorded walk: 10 s windows from the first swing-down on (the stand-up before the
    first gait phase is no walking), over the body pose and the battery power samples.

    ``./hexapod demo`` (from the samples it records) and ``./hexapod analyse`` (from the bag's
    /sim/body_pose, /power and first /swing_down, which carry the same samples) both call this, so
    one walk has one CoT."""
    return cost_of_transport(pose_t_s, pose_xy_m, power_t_s, power_w, mass_kg, gravity_mps2,
                             start_s=first_swing_down_s)


def swing_down_variances(t_imu_s, roll_rad, pitch_rad, acc_z_mps2, intervals) -> list[dict]:
    """Fig. 11: variance of roll, pitch and vertical acceleration within each (t0, t1, leg) interval."""
    t = np.asarray(t_imu_s)
    out = []
    for t0, t1, leg in intervals:
        sel = (t >= t0) & (t <= t1)
        if sel.sum() < 3:
            continue
        out.append({'leg': int(leg), 'var_roll': float(np.var(np.asarray(roll_rad)[sel])),
                    'var_pitch': float(np.var(np.asarray(pitch_rad)[sel])),
                    'var_acc_z': float(np.var(np.asarray(acc_z_mps2)[sel]))})
    return out


@dataclass
class DetectionEvent:
    """One leg's swing-down as the controller saw it, with simulation truth attached."""

    leg: int
    detector: str
    t_swing_start_s: float
    t_stop_s: float
    stop_reason: int               # 1 contact detected, 2 theta_fin reached
    t_true_contact_s: float        # first true foot contact during the swing-down (nan: none)
    t_con_s: float
    femur_torque_at_stop_nm: float
    peak_femur_torque_nm: float    # largest |femur torque| from true contact to stop + 0.1 s
    overshoot_m: float             # commanded foot below the true foot at the stop
    floor_periods: float = float('nan')   # (threshold - error) at the first read in contact / femur goal
    #                                       step: the fewest control periods in which a rigidly blocked leg
    #                                       crosses the threshold (adaptive: about epsilon / step)
    body_rise_m: float = float('nan')     # trunk's largest rise during the group's swing-down (truth)


def detection_quality(events: list[DetectionEvent]) -> dict:
    """Summary of ground-detection quality over many swing-downs."""
    if not events:
        raise MetricsError('no swing-down events to evaluate')
    contact = [e for e in events if e.stop_reason == 1]
    premature = [e for e in contact if not np.isfinite(e.t_true_contact_s) or e.t_stop_s < e.t_true_contact_s]
    valid = [e for e in contact if e not in premature]
    missed = [e for e in events if e.stop_reason == 2 and np.isfinite(e.t_true_contact_s)]
    delays = np.array([e.t_stop_s - e.t_true_contact_s for e in valid])
    periods = np.array([(e.t_stop_s - e.t_true_contact_s) / e.t_con_s for e in valid])
    tq = np.array([abs(e.femur_torque_at_stop_nm) for e in valid])
    peak = np.array([e.peak_femur_torque_nm for e in valid if np.isfinite(e.peak_femur_torque_nm)])
    over = np.array([e.overshoot_m for e in valid])
    floor = np.array([e.floor_periods for e in valid if np.isfinite(e.floor_periods)])
    beyond = np.array([(e.t_stop_s - e.t_true_contact_s) / e.t_con_s - e.floor_periods for e in valid
                       if np.isfinite(e.floor_periods)])
    rise = np.array([e.body_rise_m for e in events if np.isfinite(e.body_rise_m)])

    def stats(a):
        return {'mean': float(a.mean()), 'median': float(np.median(a)), 'p90': float(np.percentile(a, 90)),
                'max': float(a.max())} if len(a) else None

    return {'swing_downs': len(events), 'detected': len(contact), 'premature_stops': len(premature),
            'missed_contacts': len(missed), 'no_ground': sum(1 for e in events if e.stop_reason == 2
                                                             and not np.isfinite(e.t_true_contact_s)),
            'delay_s': stats(delays), 'delay_control_periods': stats(periods),
            'blocked_leg_floor_periods': stats(floor), 'delay_beyond_floor_periods': stats(beyond),
            'body_rise_m': stats(rise),
            'femur_torque_at_stop_nm': stats(tq), 'peak_femur_torque_nm': stats(peak),
            'command_overshoot_m': stats(over)}


def events_to_dicts(events: list[DetectionEvent]) -> list[dict]:
    return [asdict(e) for e in events]
