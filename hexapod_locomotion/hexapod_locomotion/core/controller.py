"""The adaptive gait cycle of the paper's Fig. 4, on any :class:`hexapod_model.bus.ServoBus`.

One *phase* moves one gait group: swing-up, swing-forward (joint-space interpolation of the foot
targets), swing-down with ground detection (Algorithm 1, :mod:`.detector`), then - once every
swinging leg has stopped - body leveling (Sec. 5, Eq. 8-10) combined with the explicit forward
motion and turning requested by the velocity command. Pure Python + numpy: time comes from the
bus, nothing reads a wall clock, so the same code runs lock-stepped in simulation, on the driver,
and behind the ROS node.

Frames: body frame x forward, y left, z up. Foot targets are planned in the body frame; the
ground is felt, never assumed, except that ``theta_fin`` is placed ``ground_depth_m`` below the
nominal stance height so contact always develops (Sec. 7).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from hexapod_locomotion.core.detector import (
    STOP_CONTACT,
    STOP_THETA_FIN,
    DetectorConfig,
    ReadResult,
    SwingDownPhase,
    run_swing_down,
)
from hexapod_locomotion.core.gait import Gait
from hexapod_locomotion.core.locomotion_params import LocomotionError, LocomotionParams, VelocityCommand
from hexapod_locomotion.core.support import support_shift
from hexapod_locomotion.core.swing_watch import in_air_rollouts, obstructed
from hexapod_model.bus import ServoBus
from hexapod_model.description import ALL_JOINTS, JOINT_ROLES, LEGS, Robot, joint_name
from hexapod_model.kinematics import UnreachableTargetError, forward, inverse, stance_feet
from hexapod_model.leveling import LevelingError, level_body
from hexapod_model.swing_model import LegModel, predict_swing_down


@dataclass
class LegOutcome:
    leg: int
    stop_reason: int
    stop_time_s: float
    stop_step: int
    peak_err_tick: float
    premature_suspects: int
    femur_step_tick: float          # |Delta theta| of the femur goal per control step (Eq. 15)
    contact_step_tick: float = float('nan')   # the same at the stop step (the approach profile's, if on)


@dataclass
class PhaseReport:
    phase: int
    legs: tuple[int, ...]
    t_start_s: float
    t_swing_down_start_s: float
    t_swing_down_end_s: float
    t_end_s: float
    outcomes: list[LegOutcome]
    body_roll_pitch_rad: tuple[float, float]
    warnings: list[str] = field(default_factory=list)


# Largest body move over the feet that stay down (GaitController._support_move). The tetrapod's case on
# the blocks needed 2.9 cm; with two legs hanging on the stairs a pentapod was moved 12-18 cm, to the
# edge of its legs' reach, and ended its walk 5 degrees off its heading.
MAX_SUPPORT_MOVE_M = 0.05


def step_within_stride(d: np.ndarray, yaw: float, stride_m: float, neutral_xy: np.ndarray) -> tuple[np.ndarray, float]:
    """The cycle's displacement ``d`` (x, y) [m] and yaw [rad] with no foothold moving further than
    ``stride_m`` per cycle. A foot lands at its neutral foothold (``neutral_xy``, 6 x 2, body frame)
    turned by yaw / 2 and advanced by d / 2, and the stance carries it to the neutral turned by -yaw / 2
    and d / 2 behind: it moves by k d + t, with t = (R(yaw/2) - R(-yaw/2)) n its part of the turn.

    The turn keeps its priority: ``d`` is shortened (the largest k <= 1) until every foothold fits, and
    only a turn that alone moves a foot further than the stride (beyond every gait's turn limit) is
    cut, with no displacement left. Without a yaw this is the stride's limit on |d| alone. With one, the
    turn adds to the stride on the feet it carries forward: a tetrapod walking at its stride while the
    course correction turned it back at 0.1 rad/s asked the hind feet for 50 % more than the stride,
    their footholds were out of reach, the leveling held the pose, and the robot stood 10 s at a block's
    edge (mockup, t_des 0.5 s, seed 32)."""
    if yaw == 0.0:
        length = float(np.linalg.norm(d))
        return (d * (stride_m / length), 0.0) if length > stride_m else (d, 0.0)
    reach = float(np.max(np.linalg.norm(neutral_xy, axis=1)))
    if 2.0 * abs(math.sin(yaw / 2)) * reach >= stride_m:      # the turn alone is too long: cut it, stand still
        return np.zeros(2), math.copysign(2.0 * math.asin(min(1.0, stride_m / (2.0 * reach))), yaw)
    dd = float(np.dot(d, d))
    if dd == 0.0:
        return d, yaw
    s = 2.0 * math.sin(yaw / 2)
    t = neutral_xy[:, ::-1] * np.array([-s, s])              # (R(yaw/2) - R(-yaw/2)) n = s (-n_y, n_x)
    # |k d + t|^2 <= stride^2 for every foot: k at most the larger root of each quadratic
    dt = t @ d
    k = float(np.min((-dt + np.sqrt(dt ** 2 - dd * (np.sum(t * t, axis=1) - stride_m ** 2))) / dd))
    return (d * k, yaw) if k < 1.0 else (d, yaw)


class GaitController:
    """Runs the adaptive gait cycle for one gait and detector on a bus."""

    def __init__(self, robot: Robot, gait: Gait, params: LocomotionParams = LocomotionParams(),
                 detector: DetectorConfig = DetectorConfig(), t_com_s: float | None = None,
                 on_read: Callable[[ReadResult], None] | None = None,
                 on_phase: Callable[[PhaseReport], None] | None = None,
                 on_swing_start: Callable[[SwingDownPhase], None] | None = None):
        self.robot = robot
        self.gait = gait
        self.params = params
        self.detector = detector
        self.t_com_s = robot.bus.t_com_s if t_com_s is None else float(t_com_s)
        self.on_read = on_read
        self.on_phase = on_phase
        self.on_swing_start = on_swing_start
        self.models = {leg: LegModel(robot, leg) for leg in LEGS}
        self.neutral = stance_feet(robot)                   # (6, 3) body frame
        self.body_height_m = -float(self.neutral[0, 2])
        self.goals = self._stance_goals()
        self.phase_index = 0
        self._pending_level: dict[str, float] | None = None  # leveling left for the next transfer
        self._rr = 0                                        # round-robin read pointer
        self._reads: dict[str, tuple[float, float]] = {}    # joint -> (theta, sample time) of its last read
        # (bus time, (femur, tibia) goals of the swinging legs) per write since the swing-up began
        self._goal_log: list[tuple[float, np.ndarray]] | None = None
        self._logged_legs: tuple[int, ...] = ()
        # feet off the ground (leg odometry, contact_legs): the group swinging now, and the legs whose
        # last swing-down found no ground (they hang at the nominal ground until they swing again)
        self.swinging: tuple[int, ...] = ()
        self.airborne: frozenset[int] = frozenset()

    def warm_up(self) -> None:
        """Compile (or load from numba's cache) the swing-down model now, before the robot moves: in
        real time, the first swing-down would otherwise stall its legs for the compile time."""
        legs = self.gait.swing_legs(0)
        angles = [self.leg_angles(leg)[1:] for leg in legs]
        predict_swing_down(self.robot, legs, angles, angles, self.params.t_des_s, self.t_com_s, n_steps=2,
                           models=self.models)
        # the rollout a stall of the host is replayed with (SwingDownPhase._hold)
        self.models[legs[0]].rollout(angles[0], [0.0, 0.0], np.full((3, 2), float(self.robot.servo.center_tick)))

    # ------------------------------------------------------------------ helpers
    def _stance_goals(self) -> dict[str, float]:
        th = self.robot.default_stance_rad
        return {joint_name(leg, r): th[i] for leg in LEGS for i, r in enumerate(JOINT_ROLES)}

    def leg_angles(self, leg: int) -> np.ndarray:
        """Commanded (coxa, femur, tibia) angles of ``leg``."""
        return np.array([self.goals[joint_name(leg, r)] for r in JOINT_ROLES])

    def contact_legs(self) -> np.ndarray:
        """Which feet (legs 1..6) are on the ground as far as the controller knows: not swinging, and
        found ground at their last swing-down."""
        return np.array([leg not in self.swinging and leg not in self.airborne for leg in LEGS])

    def foot(self, leg: int) -> np.ndarray:
        """Commanded foot-tip position of ``leg`` in the body frame."""
        return forward(self.robot, leg, self.leg_angles(leg))

    def idle_until(self, bus: ServoBus, t: float) -> None:
        """Let time pass until ``t``; with background reads, read joints round-robin meanwhile (as a
        driver's default read schedule does: the recording then holds every joint's motion)."""
        if self.params.background_reads:
            while bus.now() + self.t_com_s <= t + 1e-12:
                j = ALL_JOINTS[self._rr % len(ALL_JOINTS)]
                self._reads[j] = bus.read_position(j)
                self._rr += 1
        bus.wait_until(t)

    def move_joints(self, bus: ServoBus, target: dict[str, float], duration_s: float) -> None:
        """Linear joint-space interpolation of the given joints over ``duration_s``."""
        start = {j: self.goals[j] for j in target}
        t0 = bus.now()
        n = max(1, int(round(duration_s / self.params.write_period_s)))
        for i in range(1, n + 1):
            a = i / n
            for j, v in target.items():
                self.goals[j] = start[j] + a * (v - start[j])
            bus.sync_write({j: self.goals[j] for j in target})
            self._log_goals(bus)
            self.idle_until(bus, t0 + i * duration_s / n)

    def move_keyframes(self, bus: ServoBus, keys: dict[str, list[tuple[float, float]]], duration_s: float,
                       replan: Callable[[float], dict[str, list[tuple[float, float]]]] | None = None) -> None:
        """Piecewise-linear joint-space motion: joint -> [(t, angle), ...] with t in (0, duration_s]
        increasing, from the current goals at t = 0. ``replan(t)``, after each write: new keyframes (after t)
        for some of the joints, from their goals at t."""
        tables = {j: (np.r_[0.0, [k[0] for k in kk]], np.r_[self.goals[j], [k[1] for k in kk]]) for j, kk in keys.items()}
        t0 = bus.now()
        n = max(1, int(round(duration_s / self.params.write_period_s)))
        for i in range(1, n + 1):
            t = i * duration_s / n
            for j, (ts, vs) in tables.items():
                self.goals[j] = float(np.interp(t, ts, vs))
            bus.sync_write({j: self.goals[j] for j in keys})
            self._log_goals(bus)
            self.idle_until(bus, t0 + t)
            for j, kk in (replan(t) if replan is not None else {}).items():
                tables[j] = (np.r_[t, [k[0] for k in kk]], np.r_[self.goals[j], [k[1] for k in kk]])

    def start_ramp(self) -> float:
        """Fraction of the stride allowed in this phase: it grows over the first gait cycle, (k + 1) / n
        in phase k of n, then stays 1. From the home stance every foot starts at its neutral foothold,
        so a full stride in the first cycle leaves the feet further apart than any later cycle does
        (pentapod, 10 cm: a stance foot lifted off for up to 0.1 s in the first cycle, never later)."""
        if not self.params.start_ramp:
            return 1.0
        n = self.gait.n_phases
        return min(1.0, (self.phase_index + 1) / n)

    def _log_goals(self, bus: ServoBus) -> None:
        if self._goal_log is not None:
            self._goal_log.append((bus.now(), np.array([self.leg_angles(leg)[1:] for leg in self._logged_legs])))

    def start_speeds(self, t_end_s: float) -> np.ndarray | None:
        """(L, 2) femur and tibia speeds [rad/s] of the swinging legs at ``t_end_s`` as the swing-down
        model predicts them: each leg from rest at its goals when the swing-up began, driven by the goals
        written since (held between writes, one per servo control period). None without a log."""
        log, self._goal_log = self._goal_log, None
        rollouts = in_air_rollouts(self.models, self._logged_legs, log, self.robot.servo, t_end_s)
        return None if rollouts is None else np.array([r.qd_rad_s[-1] for r in rollouts])

    # ------------------------------------------------------------------ the cycle
    def startup(self, bus: ServoBus, duration_s: float = 0.5) -> None:
        """Move every joint to the home stance."""
        bus.sync_write(dict(self.goals))
        self.idle_until(bus, bus.now() + duration_s)

    def step_phase(self, bus: ServoBus, cmd: VelocityCommand = VelocityCommand()) -> PhaseReport:
        p = self.params
        legs = self.gait.swing_legs(self.phase_index)
        L = len(legs)
        warnings: list[str] = []
        t_start = bus.now()
        self.swinging = legs
        cycle_s = p.cycle_s(self.gait)
        yaw = float(np.clip(cmd.wz * cycle_s, -p.turn_rad(self.gait), p.turn_rad(self.gait)))
        d, yaw = step_within_stride(np.array([cmd.vx, cmd.vy]) * cycle_s, yaw,
                                    p.stride_m(self.gait) * self.start_ramp(), self.neutral[:, :2])

        # 1.-2. swing-up and swing-forward (with the pending leveling, if the transfer is overlapped):
        # the feet go to the neutral foothold advanced by half the stride (and turned)
        if p.start_in_motion or p.obstacle_lift_m > 0:
            self._logged_legs, self._goal_log = legs, []
            self._log_goals(bus)
        ground_z = self._transfer(bus, legs, d, yaw, warnings)

        # 3. swing-down with ground detection (Algorithm 1), from the measured state
        self.idle_until(bus, bus.now() + p.t_settle_s)
        init, fin, coxa, approach = [], [], [], []
        for leg in legs:
            th = self.leg_angles(leg)
            foot = self.foot(leg)
            th_fin = self._fin_angles(leg, foot, warnings)
            measured = [bus.read_position(joint_name(leg, r))[0] for r in ('femur', 'tibia')]
            init.append(measured)
            fin.append(th_fin[1:])
            coxa.append(th[0])
            approach.append(self.approach_fraction(foot[2], forward(self.robot, leg, np.r_[th[0], th_fin[1:]])[2],
                                                   ground_z[leg]))
        t_sd = bus.now()
        qd0 = self.start_speeds(t_sd) if p.start_in_motion else None
        self._goal_log = None
        phase = SwingDownPhase(self.robot, legs, coxa, init, fin, p.t_des_s, self.t_com_s, self.detector,
                               t_start_s=t_sd, models=self.models, approach_from=approach,
                               approach_rate=p.approach_rate,
                               fin_dwell_steps=int(math.ceil(p.fin_dwell_s / (L * self.t_com_s) - 1e-9)),
                               qd0_rad_s=qd0)
        if self.on_swing_start is not None:
            self.on_swing_start(phase)
        run_swing_down(bus, phase, on_read=self.on_read)
        t_sd_end = bus.now()
        outcomes = []
        no_ground = set()
        for leg in legs:
            st = phase.state[leg]
            g = phase.goals(st.stop_step)
            for j in ('femur', 'tibia'):
                self.goals[joint_name(leg, j)] = g[joint_name(leg, j)]
            if st.stop_reason == STOP_THETA_FIN:
                no_ground.add(leg)
                warnings.append(f'leg {leg}: no ground found down to theta_fin; the body is not leveled on it')
            outcomes.append(LegOutcome(leg, st.stop_reason, st.stop_time_s - t_sd, st.stop_step,
                                       st.peak_err_tick, st.premature_suspects, phase.femur_step_tick(leg),
                                       phase.femur_step_tick(leg, max(st.stop_step, 0))))
        self.swinging, self.airborne = (), frozenset((self.airborne - set(legs)) | no_ground)

        # 4. body leveling + explicit forward motion + turn (overlapped: with the next swing-up)
        landed = [o.leg for o in outcomes if o.stop_reason == STOP_CONTACT]
        target, roll_pitch, over_support = self._level_target(d * (p.explicit_forward * L / 6.0), no_ground, warnings,
                                                              landed)
        if target is not None:
            # a move over the support is done before the next group lifts, not beside its swing-up
            if p.overlap_transfer and not over_support:
                self._pending_level = target
            else:
                self.move_joints(bus, target, p.t_level_s)
        report = PhaseReport(self.phase_index, legs, t_start, t_sd, t_sd_end, bus.now(), outcomes, roll_pitch,
                             warnings)
        self.phase_index += 1
        if self.on_phase is not None:
            self.on_phase(report)
        return report

    def _transfer(self, bus: ServoBus, legs, d, yaw: float, warnings: list[str]) -> dict[int, float]:
        """Swing-up and swing-forward of ``legs``; with a pending leveling (``overlap_transfer``) the
        other legs level the body meanwhile. Returns each swinging leg's expected ground (body frame z
        after the transfer): the higher of its foothold and the nominal ground."""
        p = self.params
        level = self._pending_level
        self._pending_level = None
        start = {leg: self.foot(leg) for leg in legs}
        # the footholds in the body frame after the leveling (the frame the swing targets are in)
        end = start if level is None else {
            leg: forward(self.robot, leg, np.array([level[joint_name(leg, r)] for r in JOINT_ROLES])) for leg in legs}
        ground_z = {leg: max(float(end[leg][2]), -self.body_height_m) for leg in legs}
        lift = np.array([0.0, 0.0, p.lift_m])
        c, s = math.cos(yaw / 2), math.sin(yaw / 2)
        fwd, fwd_feet = {}, {}
        for leg in legs:
            n = self.neutral[leg - 1]
            xy = np.array([c * n[0] - s * n[1], s * n[0] + c * n[1]]) + d / 2
            fwd_feet[leg] = np.array([xy[0], xy[1], ground_z[leg] + p.lift_m])
            fwd.update(self._targets(leg, fwd_feet[leg], warnings))
        total = p.transfer_s() if level is not None else p.t_swing_up_s + p.t_swing_forward_s
        replan = self._obstacle_reflex(bus, legs, fwd_feet, total, warnings) if p.obstacle_lift_m > 0 else None
        if level is None:
            # Fig. 4 in sequence: lift the feet straight up, then carry them forward
            up = {}
            for leg in legs:
                up.update(self._targets(leg, start[leg] + lift, warnings))
            if replan is None:
                self.move_joints(bus, up, p.t_swing_up_s)
                self.move_joints(bus, fwd, p.t_swing_forward_s)
            else:       # the same motion as keyframes, which the reflex can replan
                self.move_keyframes(bus, {j: [(p.t_swing_up_s, up[j]), (total, fwd[j])] for j in fwd}, total, replan)
            return ground_z
        # overlapped: the body moves under the swinging feet, so the foot lifts straight up over its
        # foothold as the body frame is at the end of the swing-up (the body's motion is linear in time)
        a = p.t_swing_up_s / total
        up = {}
        for leg in legs:
            up.update(self._targets(leg, (1 - a) * start[leg] + a * end[leg] + lift, warnings))
        keys = {j: [(total, v)] for j, v in level.items() if j not in fwd}
        for j in fwd:
            keys[j] = [(p.t_swing_up_s, up[j]), (total, fwd[j])]
        self.move_keyframes(bus, keys, total, replan)
        return ground_z

    def _obstacle_reflex(self, bus: ServoBus, legs, fwd_feet: dict[int, np.ndarray], total_s: float,
                         warnings: list[str]) -> Callable[[float], dict[str, list[tuple[float, float]]]]:
        """The transfer's ``replan`` (:meth:`move_keyframes`): a swinging leg whose femur or tibia read is
        ``obstacle_tick`` off its motion in the air has met an obstacle; its foot goes ``obstacle_lift_m``
        higher, over the swing-up time from where its goal is, then on to its foothold that much higher."""
        p = self.params
        limit = p.obstacle_tick * self.robot.servo.rad_per_tick
        high = np.array([0.0, 0.0, p.obstacle_lift_m])
        lifted: set[int] = set()

        def replan(t: float) -> dict[str, list[tuple[float, float]]]:
            log = self._goal_log
            rollouts = in_air_rollouts(self.models, legs, log, self.robot.servo, bus.now())
            if rollouts is None:
                return {}
            reads = {leg: [self._reads.get(joint_name(leg, r)) for r in ('femur', 'tibia')]
                     for leg in legs if leg not in lifted}
            keys = {}
            for leg, off in obstructed(rollouts, legs, log[0][0], reads, limit).items():
                lifted.add(leg)
                up = self._targets(leg, self.foot(leg) + high, warnings)
                on = self._targets(leg, fwd_feet[leg] + high, warnings)
                t_up = t + p.t_swing_up_s
                keys.update({j: [(t_up, up[j]), (total_s, on[j])] if t_up < total_s else [(total_s, on[j])]
                             for j in on})
                warnings.append(f'leg {leg}: met an obstacle in its swing ({off / self.robot.servo.rad_per_tick:.0f} '
                                f'ticks off its motion in the air); lifted {p.obstacle_lift_m * 100:.1f} cm higher')
            return keys
        return replan

    def finish(self, bus: ServoBus) -> None:
        """Carry out a leveling left pending by an overlapped transfer (before standing still)."""
        if self._pending_level is not None:
            target, self._pending_level = self._pending_level, None
            self.move_joints(bus, target, self.params.t_level_s)

    def approach_fraction(self, z_start_m: float, z_fin_m: float, ground_z_m: float) -> float:
        """Fraction of the swing-down path (theta_init -> theta_fin) at which the foot is
        ``approach_height_m`` above the expected ground ``ground_z_m`` (body frame z), taking the
        foot height as linear along the joint-space path (it is within a few mm over a swing-down).
        1 when the approach profile is off."""
        if self.params.approach_rate >= 1.0 or z_start_m <= z_fin_m:
            return 1.0
        z_a = ground_z_m + self.params.approach_height_m
        return float(np.clip((z_start_m - z_a) / (z_start_m - z_fin_m), 0.0, 1.0))

    def _targets(self, leg: int, foot, warnings: list[str]) -> dict[str, float]:
        try:
            th = inverse(self.robot, leg, foot)
        except UnreachableTargetError as exc:
            # Pull the target towards the neutral foothold until it is reachable.
            n = self.neutral[leg - 1]
            for a in np.linspace(0.1, 1.0, 10):
                try:
                    th = inverse(self.robot, leg, (1 - a) * np.asarray(foot) + a * n)
                    break
                except UnreachableTargetError:
                    continue
            else:
                raise LocomotionError(f'leg {leg}: no reachable target near {np.round(foot, 3).tolist()}') from exc
            warnings.append(f'{exc}; target pulled towards the neutral foothold')
        return {joint_name(leg, r): float(v) for r, v in zip(JOINT_ROLES, th)}

    def _support_move(self, new_feet: np.ndarray, support, shift_xy, warnings: list[str]) -> np.ndarray:
        """The body move (x, y) [m], beyond ``shift_xy``, that puts its centre ``support_margin_m`` inside
        the polygon of the feet that stay on the ground while the next group swings (``support``: the
        feet that found ground) when it would be outside it; zero otherwise. Without it, a leg hanging
        where its swing-down found no ground left a tetrapod on three feet with its centre 1.5-3.5 cm
        outside them: the body tipped onto the hanging leg."""
        none = np.zeros(2)
        m = self.params.support_margin_m
        if m <= 0:
            return none
        nxt = self.gait.swing_legs(self.phase_index + 1)
        stay = [leg for leg in support if leg not in nxt and leg not in self.airborne]
        if len(stay) == len(LEGS) - len(nxt):          # every leg that stays found ground: the paper's gait
            return none
        feet_xy = new_feet[[leg - 1 for leg in stay], :2] - shift_xy
        inside = support_shift(feet_xy, 0.0)
        if inside is None or not np.any(inside):        # no polygon to move over, or the centre is inside it
            return none
        extra = support_shift(feet_xy, m)
        extra = inside if extra is None else extra
        if np.hypot(*extra) > MAX_SUPPORT_MOVE_M:
            warnings.append(f'support: legs {", ".join(map(str, stay))} do not hold the body while legs '
                            f'{", ".join(map(str, nxt))} lift, {np.hypot(*extra) * 100:.1f} cm away: not moved')
            return none
        warnings.append(f'support: body moved {np.hypot(*extra) * 100:.1f} cm over legs {", ".join(map(str, stay))} '
                        f'before legs {", ".join(map(str, nxt))} lift')
        return extra

    def _fin_angles(self, leg: int, foot, warnings: list[str]) -> np.ndarray:
        """theta_fin: the foot straight below its current position, ground_depth_m under the nominal ground."""
        depth = self.params.ground_depth_m
        for _ in range(12):
            try:
                return inverse(self.robot, leg, np.array([foot[0], foot[1], -self.body_height_m - depth]))
            except UnreachableTargetError:
                depth *= 0.7
        warnings.append(f'leg {leg}: cannot reach below the nominal ground; theta_fin at the nominal ground')
        return inverse(self.robot, leg, np.array([foot[0], foot[1], -self.body_height_m]))

    def landing_preload_rad(self, leg: int, n_support: int) -> np.ndarray:
        """Goal offset (coxa, femur, tibia) [rad] under which ``leg``'s servos push its foot down with
        ``landing_preload`` x an equal share of the body weight.

        A loaded stance leg's goals sit below its real pose by the servos' compliance deflection
        (about 8 femur ticks for a sixth of the weight); a leg stopped at contact has goals at its
        unloaded pose. Leveling all commanded feet onto one plane would leave that leg
        under-preloaded, and it is the first to lift off when the next group swings (in tetrapod, without
        this preload, a stance leg was often in the air). ``n_support`` legs share the weight. Only
        needed where the support is statically indeterminate (more than three legs).
        Static balance: gain * (goal - theta) = -J^T f with f the ground reaction on the foot. The
        servo's punch is left out on purpose: the tick of extra preload it amounts to keeps the
        support down (with the punch subtracted, 32 reads of a tetrapod's and 459 of a pentapod's 6500
        had a support foot up on flat ground, `test_support_feet_stay_down_at_every_tick_on_flat_ground`)."""
        th = self.leg_angles(leg)
        jac = np.empty((3, 3))
        h = 1e-6
        for i in range(3):
            d = np.zeros(3)
            d[i] = h
            jac[:, i] = (forward(self.robot, leg, th + d) - forward(self.robot, leg, th - d)) / (2 * h)
        f = np.array([0.0, 0.0, self.params.landing_preload * self.robot.total_mass_kg * self.robot.gravity_mps2
                      / max(n_support, 1)])
        servo = self.robot.servo
        return -(jac.T @ f) / (servo.gain_nm_per_tick / servo.rad_per_tick)

    def _level_target(self, shift_xy, no_ground: set[int], warnings: list[str], landed=()):
        """Eq. 8-10 on the support feet, then the yaw that best maps the neutral stance onto the feet
        (so the body follows turning legs) and the explicit forward shift. Returns the joint targets (None:
        no leveled pose), the body's roll and pitch, and whether it moves over its support
        (:meth:`_support_move`: to be done before the next group lifts).

        A leg that found no ground down to theta_fin (``no_ground``) carries no weight, so it is left out
        of the plane (Eq. 8-9: the body's tilt and height), but the body's position along the plane
        follows all six feet (Eq. 10's average), that leg's included where it looked for ground. The leg
        then waits over that spot at the nominal ground's height (in the air over a step-down) until it
        swings again. Centring the body on the five feet instead moved it back by about a sixth of a
        front foot's reach (4 cm) whenever a front leg found a step-down, and the feet swung later were
        placed from that body: pentapod at t_des 0.5 s on the mockup's blocks (5 seeds),
        14-18 mm of progress per phase against 20-21 mm with all six feet. A leg left hanging at
        theta_fin (tried first: 0.023 -> 0.026 m/s, 10 trials of 60 s) pulled later levelings down
        towards it, out of the legs' reach: a tripod with the fixed detector fell, tetrapod walks stalled.

        The feet are taken from the *commanded* joint angles of every leg, the stopped legs' frozen
        goals included. Loaded servos sag below their goals (about 1 cm of foot height at full
        load for the AX-12A's compliance), so mixing measured and commanded positions would place
        some feet systematically high and unload them; with all commanded feet on one plane the
        compliant servos share the load like equal springs."""
        support = [leg for leg in LEGS if leg not in no_ground]
        feet = np.array([self.foot(leg) for leg in LEGS])
        # the legs that will carry the body while the next group swings; three or fewer carry it by
        # statics whatever their preload, which then only squeezes the feet (tripod: +7 W)
        n_next = len([leg for leg in support if leg not in self.gait.swing_legs(self.phase_index + 1)])
        for leg in (landed if n_next > 3 else ()):
            feet[leg - 1] = forward(self.robot, leg, self.leg_angles(leg) + self.landing_preload_rad(leg, n_next))
        try:
            pose, _ = level_body(feet[[leg - 1 for leg in support]], self.body_height_m)
        except LevelingError as exc:
            warnings.append(f'body leveling skipped: {exc}')
            return None, (0.0, 0.0), False
        new_feet = pose.to_body(feet)
        roll_pitch = pose.roll_pitch_rad()
        idx = [leg - 1 for leg in support]
        # Eq. 10's average over all six feet, not only the support (a no-op when every leg found ground)
        new_feet[:, :2] -= new_feet[:, :2].mean(axis=0) - new_feet[idx, :2].mean(axis=0)
        move = self._support_move(new_feet, support, shift_xy, warnings)
        shift_xy = shift_xy + move
        nf = new_feet[idx, :2] - new_feet[idx, :2].mean(axis=0)
        nn = self.neutral[idx, :2] - self.neutral[idx, :2].mean(axis=0)
        yaw = math.atan2(np.sum(nn[:, 0] * nf[:, 1] - nn[:, 1] * nf[:, 0]), np.sum(nn * nf))
        for scale in (1.0, 0.5, 0.0):
            c, s = math.cos(-yaw * scale), math.sin(-yaw * scale)
            rot = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
            moved = (new_feet - np.array([shift_xy[0], shift_xy[1], 0]) * scale) @ rot.T
            for leg in no_ground:
                moved[leg - 1, 2] = self.neutral[leg - 1, 2]
            try:
                target = {}
                for leg in LEGS:
                    th = inverse(self.robot, leg, moved[leg - 1])
                    target.update({joint_name(leg, r): float(v) for r, v in zip(JOINT_ROLES, th)})
                break
            except UnreachableTargetError as exc:
                warnings.append(f'leveling: {exc}; shortening the body motion')
        else:
            warnings.append('leveling: no reachable leveled pose; holding the current pose')
            return None, roll_pitch, False
        return target, roll_pitch, bool(np.any(move))

