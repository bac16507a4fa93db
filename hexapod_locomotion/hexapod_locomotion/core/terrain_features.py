"""Terrain features per gait cycle from the servo reads and the ground detector. Plain numpy, no rclpy.

:class:`CycleFeatureExtractor` takes the controller's streams as they come - the goals written
(``/joint_commands``), the positions read (``/joint_states``), each swing-down's inputs
(``/swing_down``), the detector's reads (``/ground_detection``) and, optionally, the battery power
(``/power``) - and closes a gait cycle once every leg has swung down once: at the start of the next
swing-down, it returns the cycle's :class:`CycleFeatures`. Time is the message stamps; nothing else
is read. The same object runs in the trial runner (in process), on a bag and in the terrain node.

What a foot feels, and where it shows:

* *swing-down* (per leg, from the detector's reads): when the leg stopped (``t_stop / t_des``),
  the step the foot met there: its height (forward kinematics of the measured femur and the tibia on
  the Eq. 15 path) above the plane through the commanded feet of the legs that stood at that read,
  not above the nominal ground - the body's pose is what the previous ground left, so a foot on flat
  ground after soft or slippery ground finds it as far below the nominal as the body sank, but level
  with the other feet - how many reads the error stood above the model's (err - err_est
  > ``CONTACT_RESIDUAL_TICK``) before the stop (a soft floor gives way, so the error stands above it
  over more reads) and by how much at the stop, legs that found no ground. How fast the error grew
  before the stop is left out: it made legs on flat ground right after another class look rough
  (docs/terrain.md);
* *stance* (per joint role, the reads of legs not swinging): position error goal - read in ticks,
  its mean, spread and drift over the phase (a foot that slides or sinks changes the load);
* *leveling*: the plane through the commanded feet at each swing-down start (its tilt and the
  feet's scatter about it: what the leveling had to absorb);
* *power*: mean and spread of the battery power over the cycle (NaN when not recorded);
* *per leg* (:data:`LEG_FEATURES`, a block per leg after the cycle's features): the leg's nominal
  foot position, its latest swing-down's features, its stance error per joint role (mean, spread)
  and the error's drift over the stance phase right after its latest touchdown, each relative to the
  other legs' (the size of a stance error depends on the servo law, its pattern over the legs on the
  ground under each). The front legs meet
  a new class first; a classifier that sees the legs apart can follow them.

:data:`FEATURE_NAMES` (the cycle's :data:`CYCLE_FEATURE_NAMES`, then every leg's) orders the vector;
:data:`FEATURES_VERSION` changes whenever a feature's meaning does (a model file records it and is refused by another version).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from hexapod_model.description import ALL_JOINTS, JOINT_ROLES, LEGS, Robot, joint_name, parse_joint_name
from hexapod_model.kinematics import forward, stance_feet
from hexapod_model.servo import tick_to_theta

FEATURES_VERSION = 5
CONTACT_RESIDUAL_TICK = 2.0     # err - err_est above this counts as the leg being held by something [N]

_SWING = ('t_stop_frac', 'contact_step_mm', 'contact_reads', 'stop_residual_tick',
          'stop_margin_tick', 'init_lag_tick')
_STANCE = tuple(f'stance_{r}_{s}' for r in JOINT_ROLES for s in ('mean_tick', 'std_tick', 'drift_tick'))
CYCLE_FEATURE_NAMES = (
    tuple(f'swing_{n}_{s}' for n in _SWING for s in ('mean', 'std', 'min', 'max'))
    + ('swing_no_ground_frac',)
    + _STANCE
    + ('level_tilt_mrad', 'level_scatter_mm', 'level_height_mm', 'level_tilt_change_mrad')
    + ('power_mean_w', 'power_std_w')
    + ('legs_per_phase', 'cycle_s_per_t_des'))
# per leg: its latest swing-down in the cycle, its stance reads in the cycle and the drift of the
# error in the stance phase right after its latest touchdown (a soft floor keeps giving way there)
LEG_FEATURES = (('nominal_x_mm', 'nominal_y_mm') + _SWING + ('no_ground',)
                + tuple(f'stance_{r}_{s}' for r in JOINT_ROLES for s in ('mean_rel', 'std_rel', 'settle_rel')))
FEATURE_NAMES = CYCLE_FEATURE_NAMES + tuple(f'leg{leg}_{n}' for leg in LEGS for n in LEG_FEATURES)


@dataclass
class CycleFeatures:
    t_start_s: float                # the cycle's first swing-down start
    t_end_s: float                  # the next cycle's first swing-down start (when it was closed)
    phases: int
    values: np.ndarray              # in FEATURE_NAMES order; NaN where a stream had nothing


@dataclass
class _Phase:
    t_start_s: float
    legs: tuple[int, ...]
    t_des_s: float
    fields: dict
    det: dict = field(default_factory=dict)            # leg -> list of detector reads (tuples)
    support: dict = field(default_factory=dict)        # leg -> the support feet's plane at its stop (a, b, c)
    stance: dict = field(default_factory=dict)         # role -> list of (t, error tick)
    leg_stance: dict = field(default_factory=dict)     # (leg, role) -> list of error tick
    level: tuple = (math.nan, math.nan, math.nan)      # (tilt rad, scatter m, height m) at the start


def _get(msg, name, default=None):
    if isinstance(msg, dict):
        return msg.get(name, default)
    return getattr(msg, name, default)


class CycleFeatureExtractor:
    """Gait-cycle features from the controller's streams (see the module doc). Feed it in time order."""

    def __init__(self, robot: Robot):
        self.robot = robot
        self.servo = robot.servo
        feet = stance_feet(robot)
        self.ground_z = float(feet[0, 2])                     # nominal ground in the body frame
        self._nominal_mm = {leg: [1000.0 * float(feet[i, 0]), 1000.0 * float(feet[i, 1])] for i, leg in enumerate(LEGS)}
        self._goal = dict(zip(ALL_JOINTS, [robot.default_stance_rad[JOINT_ROLES.index(parse_joint_name(j)[1])]
                                           for j in ALL_JOINTS]))
        self._phases: list[_Phase] = []
        self._power: list[tuple[float, float]] = []
        self._last_tilt = math.nan
        self._last_phase: _Phase | None = None                  # the previous cycle's last phase

    # -- streams
    def command(self, names, positions) -> None:
        for n, p in zip(names, positions):
            if n in self._goal:
                self._goal[n] = float(p)

    def state(self, t_s: float, name: str, position: float) -> None:
        if not self._phases or name not in self._goal:
            return
        ph = self._phases[-1]
        leg, role = parse_joint_name(name)
        if leg in ph.legs:
            return
        err = (self._goal[name] - float(position)) / self.servo.rad_per_tick
        ph.stance.setdefault(role, []).append((t_s, err))
        ph.leg_stance.setdefault((leg, role), []).append(err)

    def power(self, t_s: float, watts: float) -> None:
        if math.isfinite(watts):
            self._power.append((t_s, float(watts)))

    def detection(self, msg) -> None:
        if not self._phases:
            return
        ph = self._phases[-1]
        leg = int(_get(msg, 'leg'))
        if leg not in ph.legs:
            return
        reads = ph.det.setdefault(leg, [])
        if reads and reads[-1][6]:
            return                                             # the leg has stopped
        reads.append((float(_get(msg, 't_swing_s')), float(_get(msg, 'theta_des_tick')),
                      float(_get(msg, 'theta_real_tick')), float(_get(msg, 'err_tick')),
                      float(_get(msg, 'err_est_tick')), float(_get(msg, 'threshold_tick')),
                      bool(_get(msg, 'stopped')), int(_get(msg, 'stop_reason'))))
        if reads[-1][6]:
            ph.support[leg] = self._plane([lg for lg in LEGS if lg not in ph.legs])[0]

    def swing_start(self, t_s: float, msg) -> CycleFeatures | None:
        """A swing-down began at ``t_s``; returns the features of the gait cycle it closes, if any."""
        legs = tuple(int(v) for v in _get(msg, 'legs'))
        fields = {k: list(_get(msg, k)) for k in ('coxa_rad', 'femur_init_rad', 'tibia_init_rad', 'femur_fin_rad',
                                                 'tibia_fin_rad')}
        out = None
        covered = {leg for ph in self._phases for leg in ph.legs}
        if self._phases and covered >= set(LEGS):
            out = self._close(t_s)
        ph = _Phase(t_s, legs, float(_get(msg, 't_des_s')), fields)
        ph.level = self._leveling([leg for leg in LEGS if leg not in legs])
        self._phases.append(ph)
        return out

    # -- features
    def _plane(self, support) -> tuple[np.ndarray | None, float]:
        """The plane ``z = a x + b y + c`` (body frame) through the commanded feet of the legs that carry
        the body (``support``) and the feet's scatter about it; (None, NaN) with fewer than three."""
        if len(support) < 3:
            return None, math.nan
        feet = np.array([forward(self.robot, leg, [self._goal[joint_name(leg, r)] for r in JOINT_ROLES])
                         for leg in support])
        a = np.c_[feet[:, :2], np.ones(len(feet))]
        coef, *_ = np.linalg.lstsq(a, feet[:, 2], rcond=None)
        return coef, float(np.std(feet[:, 2] - a @ coef))

    def _leveling(self, support) -> tuple[float, float, float]:
        """(tilt, scatter, height above the nominal ground) of the support feet's plane."""
        coef, scatter = self._plane(support)
        if coef is None:
            return (math.nan, math.nan, math.nan)
        return float(math.atan(math.hypot(coef[0], coef[1]))), scatter, float(coef[2] - self.ground_z)

    def _swing_leg(self, ph: _Phase, slot: int, reads) -> list[float] | None:
        stop = next((i for i, r in enumerate(reads) if r[6]), None)
        if stop is None:
            return None
        r = reads[stop]
        res = np.array([x[3] - x[4] for x in reads[:stop + 1]])
        above = res > CONTACT_RESIDUAL_TICK
        n_contact = 0
        for v in above[::-1]:
            if not v:
                break
            n_contact += 1
        f = ph.fields
        fem = float(tick_to_theta(r[2], self.servo))
        f0, f1 = f['femur_init_rad'][slot], f['femur_fin_rad'][slot]
        frac = (fem - f0) / (f1 - f0) if abs(f1 - f0) > 1e-9 else 1.0
        tib = f['tibia_init_rad'][slot] + frac * (f['tibia_fin_rad'][slot] - f['tibia_init_rad'][slot])
        foot = forward(self.robot, ph.legs[slot], [f['coxa_rad'][slot], fem, tib])
        plane = ph.support.get(ph.legs[slot])
        step = foot[2] - (plane[0] * foot[0] + plane[1] * foot[1] + plane[2]) if plane is not None else math.nan
        return [r[0] / ph.t_des_s, 1000.0 * step, float(n_contact), float(res[-1]), r[3] - r[5],
                reads[0][3] - reads[0][4], 1.0 if r[7] == 2 else 0.0]

    def _close(self, t_end: float) -> CycleFeatures:
        phases, self._phases = self._phases, []
        swing, per_leg = [], {}
        for ph in phases:
            for slot, leg in enumerate(ph.legs):
                v = self._swing_leg(ph, slot, ph.det.get(leg, []))
                if v is not None:
                    swing.append(v)
                    per_leg[leg] = v                      # the leg's latest swing-down
        s = np.array(swing) if swing else np.full((1, len(_SWING) + 1), np.nan)
        vals = []
        for i in range(len(_SWING)):
            col = s[:, i]
            vals += [_nan(np.mean, col), _nan(np.std, col), _nan(np.min, col), _nan(np.max, col)]
        vals.append(_nan(np.mean, s[:, -1]))
        for role in JOINT_ROLES:
            errs = [np.array([e for _, e in ph.stance.get(role, [])]) for ph in phases]
            allv = np.concatenate(errs) if errs else np.zeros(0)
            drift = [_half_drift(e) for e in errs if len(e) >= 4]
            vals += [_nan(np.mean, allv), _nan(np.std, allv), _nan(np.mean, np.array(drift))]
        lv = np.array([ph.level for ph in phases])
        tilt = _nan(np.mean, lv[:, 0])
        change = abs(tilt - self._last_tilt) if math.isfinite(self._last_tilt) else math.nan
        self._last_tilt = tilt
        vals += [1000.0 * tilt, 1000.0 * _nan(np.mean, lv[:, 1]), 1000.0 * _nan(np.mean, lv[:, 2]), 1000.0 * change]
        t0 = phases[0].t_start_s
        pw = np.array([w for t, w in self._power if t0 <= t < t_end])
        self._power = [(t, w) for t, w in self._power if t >= t_end]
        vals += [_nan(np.mean, pw), _nan(np.std, pw)]
        t_des = phases[0].t_des_s
        vals += [float(np.mean([len(ph.legs) for ph in phases])), (t_end - t0) / t_des]
        vals += self._leg_values(phases, per_leg)
        self._last_phase = phases[-1]
        return CycleFeatures(t0, t_end, len(phases), np.array(vals, dtype=float))

    def _leg_values(self, phases, per_leg) -> list[float]:
        """:data:`LEG_FEATURES` of every leg, in LEGS order. The stance errors are relative to the
        other legs' (see :func:`_relative`): their size depends on the servo law, their pattern over
        the legs on the ground under each."""
        seq = ([self._last_phase] if self._last_phase is not None else []) + phases
        stance = np.full((len(LEGS), len(JOINT_ROLES), 3), np.nan)
        for i, leg in enumerate(LEGS):
            after = next((seq[k] for k in range(len(seq) - 1, 0, -1)
                          if leg in seq[k - 1].legs and leg not in seq[k].legs), None)
            for j, role in enumerate(JOINT_ROLES):
                allv = np.concatenate([np.asarray(ph.leg_stance.get((leg, role), ()), dtype=float) for ph in phases])
                e = np.asarray(after.leg_stance.get((leg, role), ()), dtype=float) if after is not None else ()
                stance[i, j] = (_nan(np.mean, allv), _nan(np.std, allv), _half_drift(e) if len(e) >= 4 else math.nan)
        stance = _relative(stance)
        out = []
        for i, leg in enumerate(LEGS):
            out += self._nominal_mm[leg] + per_leg.get(leg, [math.nan] * (len(_SWING) + 1)) + stance[i].ravel().tolist()
        return out


def _relative(stance: np.ndarray) -> np.ndarray:
    """(legs, roles, [mean, spread, settle]) -> each leg's mean error in standard deviations of the
    legs' means about their mean, its spread and settle drift over the legs' mean magnitude (NaN
    where the legs give no scale)."""
    out = np.full_like(stance, np.nan)
    with np.errstate(invalid='ignore', divide='ignore'):
        for j in range(stance.shape[1]):
            m = stance[:, j, 0]
            if np.isfinite(m).sum() >= 2:
                out[:, j, 0] = (m - np.nanmean(m)) / np.nanstd(m)
            for k in (1, 2):
                v = stance[:, j, k]
                if np.isfinite(v).any():
                    out[:, j, k] = v / np.nanmean(np.abs(v))
    out[~np.isfinite(out)] = np.nan
    return out


def _nan(fn, a) -> float:
    a = np.asarray(a, dtype=float)
    a = a[np.isfinite(a)]
    return float(fn(a)) if a.size else math.nan


def _half_drift(e: np.ndarray) -> float:
    h = len(e) // 2
    return float(np.mean(e[h:]) - np.mean(e[:h]))


def feed_message(ex: CycleFeatureExtractor, topic: str, msg, t_s: float) -> CycleFeatures | None:
    """Route one message of a contract topic (a bag's or a live one; ``topic`` its contract key) to
    the extractor; returns a closed cycle's features when this message closed one."""
    from hexapod_model.contract import GROUND_DETECTION, JOINT_COMMANDS, JOINT_STATES, POWER, SWING_DOWN, stamp_seconds
    if topic == JOINT_STATES:
        names, pos = _get(msg, 'name'), _get(msg, 'position')
        t = stamp_seconds(_get(_get(msg, 'header'), 'stamp'))
        for n, p in zip(names, pos):
            ex.state(t, n, p)
    elif topic == JOINT_COMMANDS:
        ex.command(_get(msg, 'name'), _get(msg, 'position'))
    elif topic == GROUND_DETECTION:
        ex.detection(msg)
    elif topic == SWING_DOWN:
        return ex.swing_start(stamp_seconds(_get(_get(msg, 'header'), 'stamp')), msg)
    elif topic == POWER:
        v, i = float(_get(msg, 'voltage')), float(_get(msg, 'current'))
        ex.power(stamp_seconds(_get(_get(msg, 'header'), 'stamp')), abs(v * i))
    return None


def _topics():
    from hexapod_model.contract import GROUND_DETECTION, JOINT_COMMANDS, JOINT_STATES, POWER, SWING_DOWN
    return (JOINT_STATES, JOINT_COMMANDS, GROUND_DETECTION, SWING_DOWN), (POWER,)


REQUIRED_TOPICS, OPTIONAL_TOPICS = _topics()
