"""Swing-down model of one leg with its AX-12A servos (paper Sec. 6-7, Eq. 11-17). Pure numpy/numba.

Dynamics (Eq. 11 with Eq. 12 reflected to the joint, i.e. Eq. 14 in joint units): the femur and
tibia of one leg form a two-link arm in the leg's vertical plane (coxa held, body level, no ground
contact)::

    (D(q) + J R^2) q'' + C(q, q') q' + B R^2 q' + F(q') + G(q) = tau_servo

``q = (theta_2, theta_3)`` (DH joint variables, ``psi = theta + theta_off`` is the link angle
above the horizontal for the femur). ``F`` is Coulomb friction ``tau_c R`` (optionally a larger
break-away torque at rest). ``tau_servo`` is the firmware law of :mod:`hexapod_model.servo`,
recomputed every control period (1 ms) from the integer present tick and held in between.

Time stepping: ``substeps`` semi-implicit Euler steps per control period (default 1: within 0.05
tick of a 50-substep reference over the Fig. 9 swings, see the tests), damping implicit,
friction as a velocity-level impulse (so a joint at rest sticks exactly until the drive torque
exceeds the break-away torque). A velocity that reverses within a step passed through rest there,
so the impulse of that step is bounded by the break-away torque too, wherever in the step the
zero fell (bounded by the Coulomb level, a reversal stuck only when it fell near the step's end).
The kernels are compiled with numba when available: :mod:`hexapod_model.swing_kernel` (the rigid
leg, the rollout of several legs, the fused prediction below), :mod:`hexapod_model.swing_backlash`
(a leg with gear backlash), sharing the parameter vector's layout and the servo law of
:mod:`hexapod_model.swing_common`.

``predict_swing_down`` is the paper's ``CalcModel`` for L simultaneously swinging legs: it builds
the interpolated goal sequence of Eq. 15 (one new goal every ``t_con = L * T_com``), simulates the
legs and returns the predicted femur position at each sequential read of Algorithm 1 (leg ``l``
of step ``k`` is sampled at ``k t_con + l T_com``) with the Eq. 17 threshold.

Gear backlash (``backlash`` effect, used by the discrepancy tool): a joint with play splits into
the motor side (reflected rotor inertia, damping and friction, driven by the firmware torque) and
the link, coupled by a dead zone of total width ``w``; the potentiometer, and so the firmware,
sees the link. Without play the kernel runs exactly the rigid path above. :class:`CoxaModel`
reuses the same kernel for the coxa as a 1-DOF joint about the vertical axis (whole leg's inertia,
no gravity).

Sign convention for errors: the paper notes the comparison depends on the direction of motion
and on how the servo is mounted. All errors here are *lag in the direction of motion*,
``err = s (theta_des - theta)`` in ticks with ``s = sign(theta_fin - theta_init)`` of the femur,
so a leg held up by the ground shows a growing positive error.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from hexapod_model.description import JointEffects, Robot, ServoParams
from hexapod_model.dictionary import T_DS, T_K, T_MU, T_PA, T_TS, joint_terms, supply_resistance_ohm
from hexapod_model.joints import Joint
from hexapod_model.swing_common import (
    N_PARAMS,
    P_A2,
    P_B2,
    P_B3,
    P_BL2,
    P_BL3,
    P_CENTER,
    P_CONTROL,
    P_DT,
    P_FC2,
    P_FC3,
    P_FS2,
    P_FS3,
    P_G,
    P_I1,
    P_I2,
    P_J2,
    P_J3,
    P_KP,
    P_LC1,
    P_LC2,
    P_M1,
    P_M2,
    P_MARG2,
    P_MARG3,
    P_MAXTICK,
    P_OFF2,
    P_OFF3,
    P_PUNCH2,
    P_PUNCH3,
    P_RPT,
    P_SUBSTEPS,
    P_TMAX2,
    P_TMAX3,
)
from hexapod_model.swing_kernel import _rollout_legs, _swing_down_kernel


def joint_damping_nms_per_rad(servo: ServoParams, e: JointEffects, motor_scale: float = 1.0) -> float:
    """Viscous damping at one joint: the servo's reflected damping (times a motor-damping ratio and a weak
    motor's ``motor_scale``, :mod:`hexapod_model.dictionary`) plus any extra viscous damping of the joint;
    the one rule the model and the MuJoCo sim share."""
    return servo.reflected_damping_nms_per_rad * e.damping_ratio * motor_scale + e.extra_damping_nms_per_rad


_NO_GAP = np.zeros(2)


@dataclass(frozen=True)
class Rollout:
    """Result of :meth:`LegModel.rollout`: ``q[k]``/``qd[k]`` at ``t = k dt``; ``tau[k]`` held on [k, k+1)."""

    dt_s: float
    q_rad: np.ndarray
    qd_rad_s: np.ndarray
    tau_nm: np.ndarray
    gap_rad: np.ndarray | None = None   # backlash gap q_motor - q_link per joint (zeros without backlash)

    def theta_at(self, t_s) -> np.ndarray:
        """Joint angles at arbitrary times (linear interpolation between control periods)."""
        t = np.asarray(t_s, dtype=float)
        grid = np.arange(len(self.q_rad)) * self.dt_s
        return np.stack([np.interp(t, grid, self.q_rad[:, j]) for j in range(2)], axis=-1)


class LegModel:
    """The two-link swing-down model of one leg, parameters taken from the robot description."""

    def __init__(self, robot: Robot, leg: int, substeps: int = 1, control: bool = True,
                 friction: bool = True, damping: bool = True, gravity: bool = True):
        self.robot = robot
        self.leg = leg
        s = robot.servo
        femur, tibia = robot.links['femur'], robot.links['tibia']
        a2, a3 = robot.dh['femur'].a_m, robot.dh['tibia'].a_m
        m2, lc2, i2 = tibia.mass_kg, tibia.com_from_joint_m, tibia.inertia_about_com_kgm2
        payload = robot.leg_payload_kg(leg)
        if payload > 0:  # point mass at the tibia tip: combine with the tibia link
            m_tot = m2 + payload
            lc_new = (m2 * lc2 + payload * a3) / m_tot
            i2 = i2 + m2 * (lc2 - lc_new) ** 2 + payload * (a3 - lc_new) ** 2
            m2, lc2 = m_tot, lc_new
        eff = [robot.joint_effects(Joint(leg, r)) for r in ('femur', 'tibia')]
        self.terms = np.array([joint_terms(robot, Joint(leg, r)) for r in ('femur', 'tibia')])
        p = np.zeros(N_PARAMS)
        p[P_M1], p[P_LC1], p[P_I1] = femur.mass_kg, femur.com_from_joint_m, femur.inertia_about_com_kgm2
        p[P_M2], p[P_LC2], p[P_I2], p[P_A2] = m2, lc2, i2, a2
        p[P_G] = robot.gravity_mps2 if gravity else 0.0
        p[P_OFF2], p[P_OFF3] = robot.dh['femur'].theta_off_rad, robot.dh['tibia'].theta_off_rad
        p[P_J2] = p[P_J3] = s.reflected_inertia_kgm2
        for j, e in enumerate(eff):
            fc = (s.reflected_coulomb_nm + e.extra_coulomb_nm) if friction else 0.0
            p[P_B2 + j] = joint_damping_nms_per_rad(s, e, self.terms[j, T_DS]) if damping else 0.0
            p[P_FC2 + j] = fc
            p[P_FS2 + j] = max(fc, e.static_friction_nm) if friction else 0.0
            p[P_TMAX2 + j] = s.stall_torque_nm if e.torque_max_nm is None else min(s.stall_torque_nm, e.torque_max_nm)
            p[P_MARG2 + j] = s.compliance_margin_ticks + e.deadband_margin_ticks
            p[P_PUNCH2 + j] = s.punch_nm + e.extra_punch_nm
            p[P_BL2 + j] = e.backlash_width_rad
        p[P_KP] = s.gain_nm_per_tick
        p[P_RPT], p[P_CENTER], p[P_MAXTICK] = s.rad_per_tick, s.center_tick, s.max_tick
        p[P_CONTROL] = 1.0 if control else 0.0
        p[P_SUBSTEPS] = int(substeps)
        p[P_DT] = s.control_period_s
        self.params = p
        self.dt_s = s.control_period_s
        # dictionary terms (hexapod_model.swing_terms): the supply as (R / V, 1 / (K R))
        self.supply = (supply_resistance_ohm(robot) / s.supply_voltage_v,
                       1.0 / (s.torque_constant_nm_per_a * s.gear_ratio))

    @property
    def has_terms(self) -> bool:
        """Whether a dictionary term acts on this model's joints (then :func:`swing_terms.rollout_terms` runs)."""
        t = self.terms
        return bool(self.supply[0] > 0 or np.any(t[:, [T_K, T_PA, T_MU]] != 0) or np.any(t[:, T_TS] != 1.0))

    def default_gap_rad(self, q0_rad) -> np.ndarray:
        """Initial backlash gap: the motor side rests against the link on the side that carries gravity."""
        widths = self.params[[P_BL2, P_BL3]]
        if not np.any(widths > 0):
            return np.zeros(2)
        return 0.5 * widths * np.sign(self.gravity_torque_nm(np.asarray(q0_rad, dtype=float)))

    def start_gap_rad(self, q0_rad, gap0_rad=None) -> np.ndarray:
        """The initial backlash gap of a rollout: ``gap0_rad`` when given, else :meth:`default_gap_rad`
        (zeros without backlash)."""
        if gap0_rad is not None:
            return np.ascontiguousarray(gap0_rad, dtype=np.float64).reshape(2)
        if self.params[P_BL2] > 0.0 or self.params[P_BL3] > 0.0:
            return self.default_gap_rad(q0_rad)
        return _NO_GAP

    def rollout(self, q0_rad, qd0_rad_s, goal_ticks, gap0_rad=None, i_ext=None) -> Rollout:
        """Simulate from ``q0`` with integer goal ticks per control period (array of shape (n, 2)).

        ``gap0_rad``: initial backlash gap ``q_motor - q_link`` per joint (default
        :meth:`default_gap_rad`); ignored for joints without backlash. ``i_ext``: per period, the
        stall current [A] of the robot's other servos (only a supply sag uses it).
        """
        goals = np.ascontiguousarray(goal_ticks, dtype=np.float64)
        if goals.ndim != 2 or goals.shape[1] != 2:
            raise ValueError(f'goal_ticks must have shape (n, 2), got {goals.shape}')
        q0 = np.asarray(q0_rad, dtype=np.float64).reshape(2)
        qd0 = np.asarray(qd0_rad_s, dtype=np.float64).reshape(2)
        if not (np.all(np.isfinite(goals)) and np.all(np.isfinite(q0)) and np.all(np.isfinite(qd0))):
            raise ValueError('swing-down model inputs contain NaN or infinity')
        p = self.params
        if self.has_terms:
            if p[P_BL2] > 0.0 or p[P_BL3] > 0.0:
                raise ValueError('dictionary terms on a leg with gear backlash are not modelled')
            from hexapod_model.swing_terms import rollout_terms
            q, qd, tau = rollout_terms(p, self.terms, self.supply, q0, qd0, goals, i_ext)
            return Rollout(self.dt_s, q, qd, tau, np.zeros_like(q))
        gap0 = self.start_gap_rad(q0, gap0_rad)
        n = len(goals)
        q = np.empty((1, n + 1, 2))
        qd = np.empty((1, n + 1, 2))
        tau = np.empty((1, n, 2))
        gap = np.empty((1, n + 1, 2))
        _rollout_legs(p[None], q0[None], qd0[None], goals[None], 1, q, qd, tau, gap0[None], gap, np.empty(1, np.int64))
        return Rollout(self.dt_s, q[0], qd[0], tau[0], gap[0])

    # -- analysis helpers used by tests and tools
    def mass_matrix(self, q_rad) -> np.ndarray:
        p = self.params
        psi3 = q_rad[1] + p[P_OFF3]
        kc = p[P_M2] * p[P_A2] * p[P_LC2]
        d11 = p[P_M1] * p[P_LC1] ** 2 + p[P_I1] + p[P_M2] * (p[P_A2] ** 2 + p[P_LC2] ** 2) + p[P_I2] \
            + 2 * kc * math.cos(psi3) + p[P_J2]
        d12 = p[P_M2] * p[P_LC2] ** 2 + p[P_I2] + kc * math.cos(psi3)
        d22 = p[P_M2] * p[P_LC2] ** 2 + p[P_I2] + p[P_J3]
        return np.array([[d11, d12], [d12, d22]])

    def gravity_torque_nm(self, q_rad) -> np.ndarray:
        """G(q): joint torques needed to hold the leg against gravity."""
        p = self.params
        psi2, psi23 = q_rad[0] + p[P_OFF2], q_rad[0] + q_rad[1] + p[P_OFF2] + p[P_OFF3]
        g2 = p[P_G] * p[P_M2] * p[P_LC2] * math.cos(psi23)
        return np.array([p[P_G] * (p[P_M1] * p[P_LC1] + p[P_M2] * p[P_A2]) * math.cos(psi2) + g2, g2])

    def energy_j(self, q_rad, qd_rad_s) -> float:
        """Kinetic (links + reflected rotors) plus potential energy."""
        p = self.params
        qd = np.asarray(qd_rad_s)
        psi2, psi23 = q_rad[0] + p[P_OFF2], q_rad[0] + q_rad[1] + p[P_OFF2] + p[P_OFF3]
        pot = p[P_G] * ((p[P_M1] * p[P_LC1] + p[P_M2] * p[P_A2]) * math.sin(psi2)
                        + p[P_M2] * p[P_LC2] * math.sin(psi23))
        return float(0.5 * qd @ self.mass_matrix(q_rad) @ qd + pot)


def coxa_axis_inertia_kgm2(robot: Robot, leg: int, femur_rad: float, tibia_rad: float) -> float:
    """Inertia of the whole leg (links and the leg's tibia-tip payload) about the vertical coxa axis.

    The coxa link lies horizontally; femur and tibia are slender rods inclined by their link
    angles ``psi`` above the horizontal, so a rod's own inertia about the vertical through its
    COM is ``I_com cos^2(psi)``; every COM adds ``m r^2`` with ``r`` its horizontal distance from
    the axis. Rotor inertia is not included (the kernel adds ``J R^2``).
    """
    links, dh = robot.links, robot.dh
    a1, a2, a3 = dh['coxa'].a_m, dh['femur'].a_m, dh['tibia'].a_m
    psi2 = femur_rad + dh['femur'].theta_off_rad
    psi23 = psi2 + tibia_rad + dh['tibia'].theta_off_rad
    c, f, t = links['coxa'], links['femur'], links['tibia']
    r_c = c.com_from_joint_m
    r_f = a1 + f.com_from_joint_m * math.cos(psi2)
    r_t = a1 + a2 * math.cos(psi2) + t.com_from_joint_m * math.cos(psi23)
    r_tip = a1 + a2 * math.cos(psi2) + a3 * math.cos(psi23)
    inertia = (c.inertia_about_com_kgm2 + c.mass_kg * r_c ** 2
               + f.inertia_about_com_kgm2 * math.cos(psi2) ** 2 + f.mass_kg * r_f ** 2
               + t.inertia_about_com_kgm2 * math.cos(psi23) ** 2 + t.mass_kg * r_t ** 2)
    return inertia + robot.leg_payload_kg(leg) * r_tip ** 2


class CoxaModel(LegModel):
    """The coxa joint as a 1-DOF servo-driven rotation about the vertical axis (no gravity).

    The leg is treated as rigid while the coxa turns: its inertia about the axis is taken at the
    femur/tibia pose ``femur_tibia_rad`` (:func:`coxa_axis_inertia_kgm2`). It reuses the leg
    kernel with the second joint replaced by a massless, uncommanded dummy that stays at tick
    ``center`` (zero torque), so every effect (friction, damping, saturation, dead-band,
    backlash) acts exactly as on femur and tibia.
    """

    def __init__(self, robot: Robot, leg: int, femur_tibia_rad=(0.0, 0.0), substeps: int = 1):
        super().__init__(robot, leg, substeps=substeps)
        s = robot.servo
        e = robot.joint_effects(Joint(leg, 'coxa'))
        p = self.params
        p[[P_M1, P_LC1, P_M2, P_LC2, P_I2, P_A2, P_G]] = 0.0
        p[P_I1] = self._axis_inertia(femur_tibia_rad)
        fc = s.reflected_coulomb_nm + e.extra_coulomb_nm
        self.terms = np.array([joint_terms(robot, Joint(leg, 'coxa')), joint_terms(robot, None)])
        p[P_B2] = joint_damping_nms_per_rad(s, e, self.terms[0, T_DS])
        p[P_FC2] = fc
        p[P_FS2] = max(fc, e.static_friction_nm)
        p[P_TMAX2] = s.stall_torque_nm if e.torque_max_nm is None else min(s.stall_torque_nm, e.torque_max_nm)
        p[P_MARG2] = s.compliance_margin_ticks + e.deadband_margin_ticks
        p[P_PUNCH2] = s.punch_nm + e.extra_punch_nm
        p[P_BL2] = e.backlash_width_rad
        # dummy second joint: rotor only, no friction, no play, never commanded away from centre
        p[P_B3] = s.reflected_damping_nms_per_rad
        p[P_FC3] = p[P_FS3] = 0.0
        p[P_TMAX3] = s.stall_torque_nm
        p[P_MARG3] = 0.0
        p[P_PUNCH3] = 0.0
        p[P_BL3] = 0.0
        self.center_tick = float(s.center_tick)

    def _axis_inertia(self, femur_tibia_rad) -> float:
        return coxa_axis_inertia_kgm2(self.robot, self.leg, float(femur_tibia_rad[0]), float(femur_tibia_rad[1]))

    def params_at(self, femur_tibia_rad) -> np.ndarray:
        """The parameter vector with the leg at another femur/tibia pose (only the inertia about the axis
        depends on it): one model serves every pose of :func:`rollout_batch`."""
        p = self.params.copy()
        p[P_I1] = self._axis_inertia(femur_tibia_rad)
        return p

    def rollout_coxa(self, q0_rad: float, qd0_rad_s: float, goal_ticks, gap0_rad: float = 0.0, i_ext=None) -> Rollout:
        """Simulate the coxa from ``q0`` with integer goal ticks per control period (shape (n,)).

        Returns a :class:`Rollout` whose column 0 is the coxa (column 1 is the dummy joint).
        """
        goals = np.asarray(goal_ticks, dtype=np.float64)
        if goals.ndim != 1:
            raise ValueError(f'coxa goal_ticks must have shape (n,), got {goals.shape}')
        two = np.empty((len(goals), 2))
        two[:, 0] = goals
        two[:, 1] = self.center_tick
        return self.rollout([q0_rad, 0.0], [qd0_rad_s, 0.0], two, gap0_rad=[gap0_rad, 0.0], i_ext=i_ext)


def rollout_batch(params: np.ndarray, q0_rad: np.ndarray, qd0_rad_s: np.ndarray, goal_ticks: list,
                  gap0_rad: np.ndarray) -> list[np.ndarray]:
    """``q`` (n_i + 1, 2) of each of L rollouts of :meth:`LegModel.rollout` without dictionary terms, bit for
    bit: ``params`` (L, N_PARAMS) the models' parameter vectors, ``q0_rad``, ``qd0_rad_s``, ``gap0_rad``
    (L, 2) (the gap as :meth:`LegModel.start_gap_rad` gives it), ``goal_ticks`` L arrays (n_i, 2) of goal
    ticks per period. The kernel steps three legs side by side (:func:`_rollout_legs`; one rollout alone
    is stepped three times over), so the rollouts go in threes of similar length."""
    q0, qd0 = np.asarray(q0_rad, dtype=np.float64), np.asarray(qd0_rad_s, dtype=np.float64)
    if not (np.all(np.isfinite(q0)) and np.all(np.isfinite(qd0))
            and all(np.all(np.isfinite(g)) for g in goal_ticks)):
        raise ValueError('swing-down model inputs contain NaN or infinity')
    lengths = np.array([len(g) for g in goal_ticks], dtype=np.int64)
    order = np.argsort(lengths, kind='stable')
    out: list = [None] * len(goal_ticks)
    for at in range(0, len(order), 3):
        group = order[at:at + 3]
        n = int(lengths[group].max())
        goals = np.empty((len(group), max(n, 1), 2))
        for slot, i in enumerate(group):
            g = goal_ticks[i]
            goals[slot, :len(g)] = g
            goals[slot, len(g):] = g[-1] if len(g) else 0.0
        q = np.empty((len(group), n + 1, 2))
        gap = np.empty((len(group), n + 1, 2))
        _rollout_legs(np.ascontiguousarray(params[group]), np.ascontiguousarray(q0[group]),
                      np.ascontiguousarray(qd0[group]), goals, 1, q, np.empty_like(q), np.empty((len(group), n, 2)),
                      np.ascontiguousarray(gap0_rad[group], dtype=np.float64), gap, np.empty(len(group), np.int64))
        for slot, i in enumerate(group):
            out[i] = q[slot, :lengths[i] + 1]
    return out


# ----------------------------------------------------------------------------- CalcModel
class SwingDownError(ValueError):
    """Bad input to the swing-down prediction (the message names it)."""


@dataclass(frozen=True)
class SwingDownPrediction:
    """Predictions at every femur read of Algorithm 1; arrays are indexed ``[step k, leg slot l]``."""

    legs: tuple[int, ...]
    t_con_s: float
    t_com_s: float
    epsilon_tick: float
    direction: np.ndarray          # (L,) +1/-1: sign of the femur motion
    t_read_s: np.ndarray           # (K, L) read instants relative to swing-down start
    theta_des_tick: np.ndarray     # (K, L) integer femur goal in effect (written at k t_con)
    theta_est_tick: np.ndarray     # (K, L) predicted femur tick at the read instant (continuous)
    err_est_tick: np.ndarray       # (K, L) predicted lag in the direction of motion
    threshold_tick: np.ndarray     # (K, L) Eq. 17: err_est + epsilon
    reached_fin: np.ndarray        # (K,) True once the goal has reached theta_fin
    rollouts: tuple[Rollout, ...]  # full 1 kHz trajectories per leg


def goal_fraction(k, n_interp: float, approach_from=1.0, approach_rate: float = 1.0):
    """Fraction of the path theta_init -> theta_fin of the goal written at step ``k`` (scalar or array).

    Eq. 15: ``(k + 1) / n_interp`` (``n_interp = t_des / t_con``), capped at 1. With an approach
    profile (``approach_rate`` < 1, the improved touchdown beside the paper's), the goal moves at
    the Eq. 15 rate up to the fraction ``approach_from`` (where the foot nears the expected ground)
    and at ``approach_rate`` times that rate from there on: the free-swing lag, and with it the push
    of a foot that has just touched, shrinks by the same factor. ``approach_rate`` 1 is Eq. 15
    exactly (the same float operations)."""
    u = (np.asarray(k, dtype=float) + 1.0) / n_interp
    if approach_rate < 1.0:
        u = np.where(u <= approach_from, u, approach_from + approach_rate * (u - approach_from))
    return np.minimum(u, 1.0)


def steps_to_fin(n_interp: float, approach_from=1.0, approach_rate: float = 1.0) -> int:
    """Steps until the goal of :func:`goal_fraction` reaches theta_fin (the largest over legs)."""
    a = np.minimum(np.asarray(approach_from, dtype=float), 1.0)
    u_fin = a + (1.0 - a) / approach_rate if approach_rate < 1.0 else np.ones_like(a)
    return int(math.ceil(float(np.max(u_fin)) * n_interp - 1e-9))


def check_approach(approach_from, approach_rate: float, n_legs: int) -> np.ndarray:
    """The approach profile's inputs validated: ``approach_from`` as an (L,) array in [0, 1]."""
    if not (math.isfinite(approach_rate) and 0.0 < approach_rate <= 1.0):
        raise SwingDownError(f'approach_rate must be in (0, 1], got {approach_rate!r}')
    a = np.broadcast_to(np.asarray(approach_from, dtype=float), (n_legs,)).copy()
    if not (np.isfinite(a).all() and (a >= 0.0).all() and (a <= 1.0).all()):
        raise SwingDownError(f'approach_from must be fractions in [0, 1], got {a.tolist()}')
    return a


def interpolated_goals(theta_init_tick, theta_fin_tick, t_des_s: float, t_con_s: float, n_steps: int,
                       approach_from=1.0, approach_rate: float = 1.0) -> np.ndarray:
    """Eq. 15 / Algorithm 1 lines 3 and 6: ``theta_des(k) = theta_init + (k+1) dtheta``, capped at theta_fin
    (with an approach profile: :func:`goal_fraction`; ``approach_from`` scalar or per leg, the
    leading axis of the inputs).

    Returns continuous goals of shape (n_steps, ...) matching the trailing shape of the inputs.
    """
    init = np.asarray(theta_init_tick, dtype=float)
    fin = np.asarray(theta_fin_tick, dtype=float)
    n_interp = t_des_s / t_con_s
    k = np.arange(n_steps).reshape((-1,) + (1,) * init.ndim)
    a = np.asarray(approach_from, dtype=float)
    a = a.reshape(a.shape + (1,) * (init.ndim - a.ndim)) if a.ndim else a
    frac = goal_fraction(k, n_interp, a, approach_rate)
    return init + frac * (fin - init)


def goals_per_period(goal_steps: np.ndarray, t_con_s: float, dt_s: float, n_periods: int) -> np.ndarray:
    """The goal in effect at each servo control period: the latest one written at or before it."""
    t = np.arange(n_periods) * dt_s
    k = np.floor(t / t_con_s + 1e-9).astype(int)
    return goal_steps[np.clip(k, 0, len(goal_steps) - 1)]


def predict_swing_down(robot: Robot, legs, theta_init_rad, theta_fin_rad, t_des_s: float, t_com_s: float,
                       epsilon_tick: float = 3.0, n_steps: int | None = None, qd0_rad_s=None,
                       models: dict | None = None, read_delay_s=None, approach_from=1.0,
                       approach_rate: float = 1.0) -> SwingDownPrediction:
    """CalcModel for ``legs`` swinging down together, read sequentially in the given order.

    ``theta_init_rad``/``theta_fin_rad``: arrays (L, 2) of (femur, tibia) DH angles. ``n_steps``:
    control steps to predict (default: until theta_fin plus 20 % settling). ``models`` may carry
    cached :class:`LegModel` per leg. ``read_delay_s`` (L,) shifts each leg's reported sample
    earlier (a readout delay effect). ``approach_from`` (scalar or (L,)) and ``approach_rate``: the
    approach profile of the goals (:func:`goal_fraction`; rate 1 = Eq. 15).

    One compiled call (:func:`_swing_down_kernel`) expands the Eq. 15 goals, simulates every leg and
    samples the reads; Python only validates the input and allocates the result (one block).
    """
    legs = tuple(int(x) for x in legs)
    L = len(legs)
    if L == 0:
        raise SwingDownError('no legs given')
    init = np.asarray(theta_init_rad, dtype=float).reshape(L, 2)
    fin = np.asarray(theta_fin_rad, dtype=float).reshape(L, 2)
    for name, v in (('t_des_s', t_des_s), ('t_com_s', t_com_s), ('epsilon_tick', epsilon_tick)):
        if not math.isfinite(v) or (name != 'epsilon_tick' and v <= 0):
            raise SwingDownError(f'{name} must be a finite positive number, got {v!r}')
    approach = check_approach(approach_from, approach_rate, L)
    servo = robot.servo
    t_con = L * t_com_s                                         # Algorithm 1, line 1
    n_fin = steps_to_fin(t_des_s / t_con, approach, approach_rate)
    if n_steps is None:
        n_steps = int(math.ceil(n_fin * 1.2)) + 1
    qd0 = np.zeros((L, 2)) if qd0_rad_s is None else np.asarray(qd0_rad_s, dtype=float).reshape(L, 2)
    if not np.all(np.isfinite(qd0)):
        raise SwingDownError('initial joint speeds contain NaN or infinity')
    delay = np.zeros(L) if read_delay_s is None else np.asarray(read_delay_s, dtype=float).reshape(L)
    dt = servo.control_period_s
    t_read_max = (n_steps - 1) * t_con + (L - 1) * t_com_s   # lines 8-15: the last read
    n_periods = int(math.ceil(t_read_max / dt)) + 2
    params = np.empty((L, N_PARAMS))
    gap0 = np.zeros((L, 2))
    for slot, leg in enumerate(legs):
        model = (models or {}).get(leg) or LegModel(robot, leg)
        params[slot] = model.params
        if model.params[P_BL2] > 0.0 or model.params[P_BL3] > 0.0:
            gap0[slot] = model.default_gap_rad(init[slot]) if np.isfinite(init[slot]).all() else 0.0
    ratio = t_con / dt
    per_step = int(round(ratio)) if abs(ratio - round(ratio)) < 1e-9 else 0   # t_con in whole servo periods
    goal_rows = n_steps if per_step else n_periods
    # the result in one allocation: 5 (K, L) tables, the init/fin ticks (2, L, 2), the direction (L,),
    # per leg q/qd/gap (n+1, 2) and tau (n, 2); the kernel's scratch (the goals) at its end
    kl = 5 * n_steps * L
    rows = L * (n_periods + 1) * 2
    block = np.empty(kl + 5 * L + 3 * rows + L * n_periods * 2 + L * goal_rows * 2)
    tables = block[:kl].reshape(5, n_steps, L)
    ticks = block[kl:kl + 4 * L].reshape(2, L, 2)
    direction = block[kl + 4 * L:kl + 5 * L]
    o = kl + 5 * L
    q, qd, gap = (block[o + i * rows:o + (i + 1) * rows].reshape(L, n_periods + 1, 2) for i in range(3))
    o += 3 * rows
    tau = block[o:o + L * n_periods * 2].reshape(L, n_periods, 2)
    goal_buf = block[o + L * n_periods * 2:].reshape(L, goal_rows, 2)
    reached = np.empty(n_steps, dtype=np.bool_)
    if not _swing_down_kernel(params, init, fin, qd0, gap0, float(t_des_s / t_con), approach, float(approach_rate),
                              n_fin, t_con, per_step,
                              float(t_com_s), delay, float(servo.center_tick), float(servo.rad_per_tick),
                              float(epsilon_tick), ticks, direction, reached, goal_buf, np.empty(L, np.int64),
                              tables[0], tables[1], tables[2], tables[3], tables[4], q, qd, tau, gap):
        raise SwingDownError('initial or final joint angles contain NaN or infinity')
    rollouts = tuple(Rollout(dt, q[slot], qd[slot], tau[slot], gap[slot]) for slot in range(L))
    return SwingDownPrediction(
        legs=legs, t_con_s=t_con, t_com_s=t_com_s, epsilon_tick=float(epsilon_tick), direction=direction,
        t_read_s=tables[0], theta_des_tick=tables[1], theta_est_tick=tables[2], err_est_tick=tables[3],
        threshold_tick=tables[4], reached_fin=reached, rollouts=rollouts)
