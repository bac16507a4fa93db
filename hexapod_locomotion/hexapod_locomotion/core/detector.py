"""Ground detection in the swing-down phase (paper Sec. 7, Algorithm 1). Pure numpy.

Two detectors share one interface:

* ``adaptive`` - the paper's model-based threshold, Eq. 17: ``e_thld(k) = err_est(k) + epsilon``,
  with ``err_est`` from the swing-down model (:func:`hexapod_model.swing_model.predict_swing_down`)
  evaluated at each read's time after the write of its step (:meth:`SwingDownPhase.model_time_s`);
* ``fixed`` - the baseline of the earlier work: a constant ``e_thld`` (21 ticks).

:class:`SwingDownPhase` is Algorithm 1 as a state machine: ``goals(k)`` gives the interpolated
goals of step ``k`` (Eq. 15, lines 5-7), ``on_read`` takes one sequential femur read (lines 9-14)
and decides whether that leg stops. It never reads a clock: times are arguments. The same object
drives the lock-stepped simulation loop (:func:`run_swing_down`) and the ROS node.

Errors are lag in the direction of motion, in ticks (see :mod:`hexapod_model.swing_model`).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from hexapod_model.bus import ServoBus
from hexapod_model.description import Robot, joint_name
from hexapod_model.kinematics import forward
from hexapod_model.param_schema import ParameterError, param, specs, validate
from hexapod_model.servo import theta_to_tick, tick_to_theta
from hexapod_model.swing_model import (
    LegModel,
    Rollout,
    SwingDownError,
    SwingDownPrediction,
    check_approach,
    goal_fraction,
    interpolated_goals,
    predict_swing_down,
    steps_to_fin,
)

STOP_NONE, STOP_CONTACT, STOP_THETA_FIN = 0, 1, 2     # as in hexapod_msgs/LegGroundDetection
STAMP_RESOLUTION_S = 1e-9                            # ROS stamps are whole nanoseconds


DETECTOR_KINDS = ('adaptive', 'fixed')              # Eq. 17, and the fixed threshold of the earlier work
STOP_MODES = ('hold', 'freeze')


class DetectorError(ValueError):
    """Bad detector configuration or input."""


@dataclass(frozen=True)
class DetectorConfig:
    """The ground detector's settings, each declared once (:func:`hexapod_model.param_schema.param`):
    locomotion_node's parameters, the trial fields and the SwingDownStart fields of a recording are
    derived from them; ``exposed=False`` marks the library settings that are no node parameters."""

    detector: str = param('adaptive', "ground detection: 'adaptive' (model threshold, Eq. 17) or 'fixed' "
                          '(constant baseline threshold)', choices=DETECTOR_KINDS)
    epsilon_tick: float = param(3.0, 'Eq. 17 margin [ticks] (paper: 3); too small stops legs early, too large '
                                'stops late', min=0.0)
    # Eq. 17 margin while a leg dwells at theta_fin (SwingDownPhase fin_dwell_steps > 0, the improved
    # touchdown; Algorithm 1 has no dwell). The goal stands still there and the modelled leg settles
    # to rest, so the model needs no margin for the goal's motion: a contact at the end of a slow
    # approach adds under epsilon_tick to the error and was missed (most of the improved touchdown's
    # missed contacts in the table4 trials). Below about 1 tick the servo's own quantisation decides.
    dwell_epsilon_tick: float = param(3.0, 'Eq. 17 margin [ticks] while a leg dwells at theta_fin (fin_dwell_s '
                                      '> 0): the goal stands still there, so a smaller margin finds a contact at '
                                      'the end of a slow approach; too small and a free leg at theta_fin is taken '
                                      "for a contact (leveled on ground that is not there); the default is Eq. 17's "
                                      "3 ticks, the experiments' improved touchdown uses 1", min=0.0)
    fixed_threshold_tick: float = param(21.0, 'baseline threshold [ticks] of the fixed detector (the earlier '
                                        'work)', min=0.0)
    min_descent_m: float = param(0.004, 'a detection before the foot has descended this much [m] is suspect',
                                 min=0.0, exposed=False)
    confirm_reads: int = param(3, '...and must then persist for this many consecutive reads', min=1, exposed=False)
    # How a stopped leg is held. 'freeze': theta_des stops where it is (Delta theta = 0, paper Sec. 7);
    # the free-swing lag frozen into the goal then keeps pushing and can lift the body off the
    # other feet. 'hold': the femur goal is set to the measured position plus an epsilon preload
    # toward the ground, so the foot rests where it touched with a small force.
    stop_mode: str = param('hold', "how a stopped leg is held: 'hold' (at the measured position, pressed "
                           "epsilon_tick toward the ground) or 'freeze' (the goal stops where it is)",
                           choices=STOP_MODES, exposed=False)

    def __post_init__(self):
        try:
            validate(self)
        except ParameterError as exc:
            raise DetectorError(f'detector {exc}') from None


# The settings a recording carries in each SwingDownStart (hexapod_msgs/msg/SwingDownStart.msg), by
# their names here: all but how a stopped leg is held, which a replay takes as configured.
RECORDED_SETTINGS = tuple(n for n in specs(DetectorConfig, library=True) if n != 'stop_mode')


@dataclass
class ReadResult:
    """Telemetry of one femur read (fields of hexapod_msgs/LegGroundDetection)."""

    leg: int
    detector: str
    step: int
    t_swing_s: float
    stamp_s: float
    theta_des_tick: float
    theta_real_tick: float
    theta_est_tick: float
    err_tick: float
    err_est_tick: float
    threshold_tick: float
    stopped: bool
    stop_reason: int
    premature_suspect: bool = False


@dataclass
class LegState:
    leg: int
    theta_init: np.ndarray          # (femur, tibia) [rad]
    theta_fin: np.ndarray
    direction: float                # sign of the femur motion
    coxa_rad: float
    goal_tick: np.ndarray           # current continuous goal (femur, tibia) [tick]
    stopped: bool = False
    stop_reason: int = STOP_NONE
    stop_step: int = -1
    stop_time_s: float = math.nan
    stop_theta_real_rad: float = math.nan
    suspect_count: int = 0
    premature_suspects: int = 0
    peak_err_tick: float = -math.inf
    history: list = field(default_factory=list)


class SwingDownPhase:
    """Algorithm 1 for the legs of one group swinging down together, read in the given order.

    ``approach_from`` (per leg, fraction of the path theta_init -> theta_fin) and ``approach_rate``
    select the goal profile (:func:`hexapod_model.swing_model.goal_fraction`): rate 1 is the paper's
    Eq. 15; below 1 the goal slows to that fraction of the Eq. 15 rate from ``approach_from`` on
    (the improved touchdown). The model prediction (CalcModel) uses the same profile.
    ``fin_dwell_steps``: a leg whose goal has reached theta_fin is still read (and may still stop on
    contact, against the model's prediction of the free leg settling) for this many more steps
    before it stops at theta_fin; 0 is Algorithm 1 (stop at theta_fin at once)."""

    def __init__(self, robot: Robot, legs, coxa_rad, theta_init_rad, theta_fin_rad, t_des_s: float,
                 t_com_s: float, config: DetectorConfig, t_start_s: float = 0.0,
                 models: dict[int, LegModel] | None = None, approach_from=1.0, approach_rate: float = 1.0,
                 fin_dwell_steps: int = 0, qd0_rad_s=None):
        self.robot = robot
        self.legs = tuple(int(x) for x in legs)
        self.config = config
        L = len(self.legs)
        init = np.asarray(theta_init_rad, dtype=float).reshape(L, 2)
        fin = np.asarray(theta_fin_rad, dtype=float).reshape(L, 2)
        qd0 = np.zeros((L, 2)) if qd0_rad_s is None else np.asarray(qd0_rad_s, dtype=float).reshape(L, 2)
        if not (np.all(np.isfinite(init)) and np.all(np.isfinite(fin)) and np.all(np.isfinite(qd0))):
            raise DetectorError('swing-down start or final angles (or start speeds) contain NaN')
        # (femur, tibia) speed of each leg at the start [rad/s], where the model starts (0: at rest)
        self.qd0_rad_s = qd0
        self.t_des_s = float(t_des_s)
        self.t_com_s = float(t_com_s)
        self.t_con_s = L * self.t_com_s                                   # line 1
        try:
            self.approach_from = check_approach(approach_from, approach_rate, L)
        except SwingDownError as exc:
            raise DetectorError(str(exc)) from None
        self.approach_rate = float(approach_rate)
        if int(fin_dwell_steps) != fin_dwell_steps or fin_dwell_steps < 0:
            raise DetectorError(f'fin_dwell_steps must be a whole number >= 0, got {fin_dwell_steps!r}')
        self.fin_dwell_steps = int(fin_dwell_steps)
        # steps until each leg's goal reaches theta_fin; n_interp: the slowest leg's
        self._n_fin = [steps_to_fin(self.t_des_s / self.t_con_s, a, self.approach_rate) for a in self.approach_from]
        self.n_interp = max(self._n_fin)
        self.t_start_s = float(t_start_s)
        servo = robot.servo
        self._init_tick = theta_to_tick(init, servo)
        self._fin_tick = theta_to_tick(fin, servo)
        # Eq. 15 (or its approach profile): the whole goal table, (n_interp, L, 2) continuous ticks
        self._goal_table = interpolated_goals(self._init_tick, self._fin_tick, self.t_des_s, self.t_con_s,
                                              self.n_interp, self.approach_from, self.approach_rate)
        self.state = {}
        for slot, leg in enumerate(self.legs):
            d = 1.0 if self._fin_tick[slot, 0] >= self._init_tick[slot, 0] else -1.0
            self.state[leg] = LegState(leg, init[slot], fin[slot], d, float(np.asarray(coxa_rad)[slot]),
                                       self._init_tick[slot].copy())
        # The model prediction of the whole phase (CalcModel); also used at the actual read stamps.
        self.prediction: SwingDownPrediction | None = None
        if config.detector == 'adaptive':
            self.prediction = predict_swing_down(robot, self.legs, init, fin, t_des_s, t_com_s,
                                                 epsilon_tick=config.epsilon_tick, qd0_rad_s=qd0,
                                                 n_steps=self.n_interp + 1 + self.fin_dwell_steps, models=models,
                                                 approach_from=self.approach_from, approach_rate=self.approach_rate)
        self._start_foot_z = {leg: forward(robot, leg, [self.state[leg].coxa_rad, *init[i]])[2]
                              for i, leg in enumerate(self.legs)}
        self._write_s: dict[int, float] = {}       # step -> time its goals were written (bus time base)
        # The model's timeline: goal k applies at _t_goal[k] on the rollouts' time axis (k t_con
        # until a stall is replayed into them, see _hold)
        self._models = dict(models or {})
        self._rollouts = list(self.prediction.rollouts) if self.prediction is not None else []
        n_goals = self.n_interp + 1 + self.fin_dwell_steps
        self._t_goal = np.arange(n_goals + 1) * self.t_con_s
        self.retimed_steps: list[int] = []          # steps whose hold was replayed into the model

    # ---------------------------------------------------------------- Algorithm 1
    @property
    def done(self) -> bool:
        return all(s.stopped for s in self.state.values())

    def goals(self, k: int) -> dict[str, float]:
        """Goals written at step ``k`` (lines 5-7): interpolated toward theta_fin, frozen once stopped."""
        out = {}
        for slot, leg in enumerate(self.legs):
            s = self.state[leg]
            if not s.stopped:
                s.goal_tick = self._goal_table[min(k, self.n_interp - 1), slot].copy()
            th = tick_to_theta(np.rint(s.goal_tick), self.robot.servo)
            out[joint_name(leg, 'coxa')] = s.coxa_rad
            out[joint_name(leg, 'femur')] = float(th[0])
            out[joint_name(leg, 'tibia')] = float(th[1])
        return out

    def femur_step_tick(self, leg: int, k: int | None = None) -> float:
        """|Delta theta| of ``leg``'s femur goal per control step at step ``k`` (Eq. 15, or the approach
        profile; default: the Eq. 15 step) [ticks]. With the leg held rigidly at contact its error
        grows by this much per t_con, so an Eq. 17 margin of epsilon needs at least epsilon / step
        control periods to be crossed."""
        slot = self.legs.index(leg)
        n = self.t_des_s / self.t_con_s
        a = self.approach_from[slot]
        frac = 1.0 / n if k is None else float(goal_fraction(k, n, a, self.approach_rate)
                                                - goal_fraction(k - 1, n, a, self.approach_rate))
        return float(abs(self._fin_tick[slot, 0] - self._init_tick[slot, 0]) * frac)

    def reached_fin(self, k: int, leg: int | None = None) -> bool:
        """The goal of step ``k`` is theta_fin (for ``leg``; default: for every leg)."""
        n = self.n_interp if leg is None else self._n_fin[self.legs.index(leg)]
        return k + 1 >= n

    def wrote(self, k: int, t_s: float) -> None:
        """The goals of step ``k`` were written at ``t_s`` (what ``sync_write`` returned)."""
        if not math.isfinite(t_s):
            raise DetectorError(f'step {k}: write time is not finite ({t_s!r})')
        self._write_s[k] = float(t_s)
        prev = self._write_s.get(k - 1)
        if prev is not None:
            held, assumed = t_s - prev, self._goal_time(k) - self._goal_time(k - 1)
            # goal k - 1 was held longer than the model has it (by more than one t_con): replay the hold
            if held > assumed + self.t_con_s or (k - 1 in self.retimed_steps and abs(held - assumed) > self.t_con_s):
                self._hold(k - 1, held)

    def model_time_s(self, k: int, stamp_s: float) -> float:
        """Where on the model's time axis a read of step ``k`` sampled at ``stamp_s`` lies.

        The model (CalcModel) applies goal ``k`` at exactly k t_con. A real computer writes it
        late now and then (the controller computed, the bus was busy), and the goal sequence is
        indexed by step, not by time: with ``err_est`` taken at the read's time since the phase
        began, every late step moved the prediction on while the goal stood still, so the measured
        error ran ahead of the threshold and free legs stopped in the air (the real-time robot
        stopped its swing-downs 70-130 ms in, 0.44 s before the ground). A read is therefore
        placed at the model's instant of its own step's write plus its time since that write
        (:meth:`wrote`). A step a little late gave the leg extra time to follow the previous goal,
        so its real error is, if anything, below the prediction: late steps can delay a detection
        but not fake one. A stall (the host paused, a read was retried) holds a goal for much
        longer than t_con: the leg comes to rest at it and afterwards lags again from zero, which
        a prediction of a leg that never stopped does not show; such a hold is replayed into the
        model (:meth:`_hold`). Without a recorded write the nominal instant t_start + k t_con
        stands in; on a bus that keeps the schedule (the simulation, lock-step) both are the read's
        time since the phase began."""
        w = self._write_s.get(k)
        if w is None:
            return stamp_s - self.t_start_s
        since = stamp_s - w
        if since > self._goal_time(k + 1) - self._goal_time(k) + self.t_con_s:
            # a stall between this step's write and its reads: goal k held at least until this
            # read and the rest of this step's reads (the next write, if later, corrects it)
            self._hold(k, since + self.t_con_s)
        return self._goal_time(k) + since

    def _goal_time(self, k: int) -> float:
        """When goal ``k`` applies on the model's time axis (k t_con unless a hold was replayed)."""
        last = len(self._t_goal) - 1
        return float(self._t_goal[min(k, last)]) + max(0, k - last) * self.t_con_s

    def _hold(self, k: int, hold_s: float) -> None:
        """Re-simulate the model from its state when goal ``k`` was applied, with goal ``k`` held for
        ``hold_s`` and the later goals one t_con apart after it (what the bus did, not the schedule).
        Only for the adaptive detector and a t_con that is a whole number of servo periods."""
        if not self._rollouts or k >= len(self._t_goal) - 1:
            return
        dt = self._rollouts[0].dt_s
        per = self.t_con_s / dt
        if abs(per - round(per)) > 1e-9:
            return
        per = int(round(per))
        n_hold = max(per, int(round(hold_s / dt)))
        p0 = int(round(self._t_goal[k] / dt))
        if p0 >= len(self._rollouts[0].q_rad):
            return
        n_goals = len(self._t_goal) - 1
        rest = n_goals - 1 - k                             # goals after k
        L = len(self.legs)
        for slot, leg in enumerate(self.legs):
            ro = self._rollouts[slot]
            table = np.rint(self._goal_table[np.minimum(np.arange(k, n_goals), self.n_interp - 1), slot])
            goals = np.concatenate([np.repeat(table[:1], n_hold, axis=0), np.repeat(table[1:], per, axis=0),
                                    np.repeat(table[-1:], L * per + 2, axis=0)])
            model = self._models.get(leg)
            if model is None:
                model = self._models[leg] = LegModel(self.robot, leg)
            gap0 = ro.gap_rad[p0] if ro.gap_rad is not None else None
            new = model.rollout(ro.q_rad[p0], ro.qd_rad_s[p0], goals, gap0_rad=gap0)
            self._rollouts[slot] = Rollout(dt, np.concatenate([ro.q_rad[:p0], new.q_rad]),
                                           np.concatenate([ro.qd_rad_s[:p0], new.qd_rad_s]),
                                           np.concatenate([ro.tau_nm[:p0], new.tau_nm]),
                                           None if ro.gap_rad is None else np.concatenate([ro.gap_rad[:p0], new.gap_rad]))
        self._t_goal[k + 1:] = self._t_goal[k] + n_hold * dt + np.arange(rest + 1) * self.t_con_s
        if not self.retimed_steps or self.retimed_steps[-1] != k:
            self.retimed_steps.append(k)

    def on_read(self, k: int, leg: int, theta_real_rad: float, stamp_s: float) -> ReadResult:
        """Lines 9-14 for one femur read of ``leg`` at step ``k``, sampled at ``stamp_s``."""
        s = self.state[leg]
        if not math.isfinite(theta_real_rad) or not math.isfinite(stamp_s):
            raise DetectorError(f'leg {leg}: femur read is not finite ({theta_real_rad!r} at {stamp_s!r})')
        servo = self.robot.servo
        slot = self.legs.index(leg)
        t_swing = stamp_s - self.t_start_s
        t_model = self.model_time_s(k, stamp_s)
        des = float(np.rint(s.goal_tick[0]))
        real = float(theta_to_tick(theta_real_rad, servo))
        err = s.direction * (des - real)                                   # Eq. 16
        if self.prediction is not None:
            ro = self._rollouts[slot]
            est = float(theta_to_tick(np.interp(t_model, np.arange(len(ro.q_rad)) * ro.dt_s, ro.q_rad[:, 0]), servo))
            err_est = s.direction * (des - est)
            dwelling = self.fin_dwell_steps > 0 and k >= self._n_fin[slot]
            thld = err_est + (self.config.dwell_epsilon_tick if dwelling else self.config.epsilon_tick)   # Eq. 17
        else:
            est, err_est = math.nan, math.nan
            thld = self.config.fixed_threshold_tick
        suspect = False
        if not s.stopped:
            s.peak_err_tick = max(s.peak_err_tick, err)
            if err > thld:
                foot_z = forward(self.robot, leg, [s.coxa_rad, theta_real_rad, tick_to_theta(s.goal_tick[1], servo)])[2]
                descended = self._start_foot_z[leg] - foot_z
                if descended < self.config.min_descent_m:
                    # The foot has hardly moved: the error cannot come from ground it has not reached.
                    suspect = True
                    s.suspect_count += 1
                    s.premature_suspects += 1
                    if s.suspect_count >= self.config.confirm_reads:
                        self._stop(s, STOP_CONTACT, k, stamp_s, theta_real_rad)
                else:
                    self._stop(s, STOP_CONTACT, k, stamp_s, theta_real_rad)
            else:
                s.suspect_count = 0
                if self.reached_fin(k - self.fin_dwell_steps, leg):
                    self._stop(s, STOP_THETA_FIN, k, stamp_s, theta_real_rad)
        res = ReadResult(leg=leg, detector=self.config.detector, step=k, t_swing_s=t_swing, stamp_s=stamp_s,
                         theta_des_tick=des, theta_real_tick=real, theta_est_tick=est, err_tick=err,
                         err_est_tick=err_est, threshold_tick=thld, stopped=s.stopped,
                         stop_reason=s.stop_reason, premature_suspect=suspect)
        s.history.append(res)
        return res

    def _stop(self, s: LegState, reason: int, k: int, stamp_s: float, theta_real_rad: float) -> None:
        s.stopped, s.stop_reason, s.stop_step, s.stop_time_s = True, reason, k, stamp_s
        s.stop_theta_real_rad = theta_real_rad
        if reason == STOP_CONTACT and self.config.stop_mode == 'hold':
            # the foot rests where it touched, pressed epsilon ticks further toward the ground
            real = float(theta_to_tick(theta_real_rad, self.robot.servo))
            s.goal_tick = np.array([real + s.direction * self.config.epsilon_tick, s.goal_tick[1]])


def run_swing_down(bus: ServoBus, phase: SwingDownPhase, on_read=None, max_steps: int | None = None) -> SwingDownPhase:
    """Execute Algorithm 1 on a bus: write goals every t_con, read each femur in order. A step that
    comes late (a busy computer) delays the rest of the phase rather than shortening later steps.

    Every leg of the group is read in every step (stopped ones too), so the read instants stay on
    the schedule the model predicted (k t_con + l T_com).
    """
    limit = max_steps if max_steps is not None else phase.n_interp + phase.fin_dwell_steps + 5
    k = 0
    t_next = phase.t_start_s
    while not phase.done:
        if k >= limit:
            raise DetectorError(f'swing-down did not finish within {limit} steps')
        bus.wait_until(t_next - STAMP_RESOLUTION_S)   # bus times are sums of stamps: due within 1 ns
        t_write = bus.sync_write(phase.goals(k))                        # line 7
        phase.wrote(k, t_write)
        # Each goal stands for t_con, as the model applies it. After a late step the schedule moves
        # on from that step's write instead of catching up: two goals written back to back would
        # drive the leg ahead of what the model predicts for them and could fake a contact.
        t_next = t_write + phase.t_con_s
        for leg in phase.legs:                                          # lines 8-15
            theta, stamp = bus.read_position(joint_name(leg, 'femur'))
            res = phase.on_read(k, leg, theta, stamp)
            if on_read is not None:
                on_read(res)
        k += 1
    return phase


def replay_swing_down(phase: SwingDownPhase, reads, on_read=None, writes=()) -> SwingDownPhase:
    """Re-run Algorithm 1 offline on recorded femur reads ``(leg, theta_rad, stamp_s)`` in bus order.

    ``writes``: the recorded stamps of the phase's goal writes, one per step in order (from
    ``/joint_commands``), so the model is read where the live controller read it
    (:meth:`SwingDownPhase.model_time_s`); steps beyond them use the nominal schedule.

    The reads of step ``k`` are the k-th run of one read per leg in ``phase.legs`` order (every leg
    is read in every step, stopped ones included, see :func:`run_swing_down`). Decisions are only
    meaningful while the recording's own controller kept moving the leg: once it froze a leg's goal,
    later reads of that leg no longer show what the replayed detector would have commanded.
    """
    L = len(phase.legs)
    k, slot = 0, 0
    for leg, theta, stamp in reads:
        if phase.done:
            break
        if leg != phase.legs[slot]:
            raise DetectorError(f'recorded reads out of Algorithm 1 order: expected leg {phase.legs[slot]} '
                                f'at step {k}, got leg {leg} at t={stamp:.4f} s')
        if slot == 0:
            phase.goals(k)
            if k < len(writes):
                phase.wrote(k, writes[k])
        res = phase.on_read(k, leg, theta, stamp)
        if on_read is not None:
            on_read(res)
        slot += 1
        if slot == L:
            slot, k = 0, k + 1
    return phase


def swing_start_fields(phase: SwingDownPhase) -> dict:
    """The fields of hexapod_msgs/msg/SwingDownStart (minus the header) for a phase."""
    st = [phase.state[leg] for leg in phase.legs]
    return {'legs': list(phase.legs), 'coxa_rad': [s.coxa_rad for s in st],
            'femur_init_rad': [float(s.theta_init[0]) for s in st], 'tibia_init_rad': [float(s.theta_init[1]) for s in st],
            'femur_fin_rad': [float(s.theta_fin[0]) for s in st], 'tibia_fin_rad': [float(s.theta_fin[1]) for s in st],
            't_des_s': phase.t_des_s, 't_com_s': phase.t_com_s,
            **{name: getattr(phase.config, name) for name in RECORDED_SETTINGS},
            'approach_rate': phase.approach_rate,
            'approach_from': [float(a) for a in phase.approach_from], 'fin_dwell_steps': phase.fin_dwell_steps,
            'femur_init_rad_s': [float(v) for v in phase.qd0_rad_s[:, 0]],
            'tibia_init_rad_s': [float(v) for v in phase.qd0_rad_s[:, 1]]}


def _field(f, name: str, default=None):
    """A SwingDownStart field of ``f`` (dict or message); ``default`` for one that older recordings lack."""
    return f.get(name, default) if isinstance(f, dict) else getattr(f, name, default)


def detector_from_fields(f, kind: str | None = None) -> DetectorConfig:
    """The detector of a recorded SwingDownStart (dict or message), optionally of the other ``kind``."""
    table = specs(DetectorConfig, library=True)
    values = {name: _field(f, name) for name in RECORDED_SETTINGS}
    # before the dwell's own margin existed the dwell used Eq. 17's
    if values['dwell_epsilon_tick'] is None:
        values['dwell_epsilon_tick'] = values['epsilon_tick']
    if kind:
        values['detector'] = kind
    return DetectorConfig(**{name: table[name].type(v) for name, v in values.items()})


def phase_from_fields(robot: Robot, f, t_start_s: float, kind: str | None = None,
                      models: dict[int, LegModel] | None = None) -> SwingDownPhase:
    """Rebuild a :class:`SwingDownPhase` from SwingDownStart fields (dict or message), optionally
    with the other detector ``kind``."""
    # recordings made before the approach profile existed carry neither field: Eq. 15
    rate = float(_field(f, 'approach_rate', 1.0))
    frm = list(_field(f, 'approach_from', ()))
    dwell = int(_field(f, 'fin_dwell_steps', 0))
    # nor the start speeds before the model started from the leg's motion: at rest
    speeds = [list(_field(f, n, ())) for n in ('femur_init_rad_s', 'tibia_init_rad_s')]
    legs = [int(x) for x in _field(f, 'legs')]
    init = np.column_stack([_field(f, 'femur_init_rad'), _field(f, 'tibia_init_rad')])
    fin = np.column_stack([_field(f, 'femur_fin_rad'), _field(f, 'tibia_fin_rad')])
    return SwingDownPhase(robot, legs, list(_field(f, 'coxa_rad')), init, fin, float(_field(f, 't_des_s')),
                          float(_field(f, 't_com_s')), detector_from_fields(f, kind), t_start_s=t_start_s,
                          models=models, approach_from=frm if len(frm) else 1.0,
                          approach_rate=rate if rate > 0 else 1.0, fin_dwell_steps=dwell,
                          qd0_rad_s=np.column_stack(speeds) if all(len(v) == len(legs) for v in speeds) else None)
