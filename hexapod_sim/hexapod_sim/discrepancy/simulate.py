"""Step 1, simulate: replay the recorded goals through the model and predict every recorded read.

Timing convention (the project's servo contract): the firmware runs at integer multiples of the
control period (1 ms); a goal written at ``t`` takes effect at the first firmware tick at or
after ``t``; a read reports the position at its stamp (the start of the read transaction), minus
any readout delay. A goal latency (a servo-law effect: every goal acts that much later) moves the
whole response of a free leg later by the same time, so it is predicted the same way, as a
shift of the prediction at the reads: the replay cannot tell it from a readout delay of every joint.
Femur and tibia of a leg are replayed together through the two-link
:class:`~hexapod_model.swing_model.LegModel`; the coxa through the 1-DOF
:class:`~hexapod_model.swing_model.CoxaModel` (whole leg's inertia about the vertical axis, no
gravity) at the leg's typical femur/tibia pose while the coxa moves.

Replays run per *segment*: a time span in which the leg hangs free. On a stand that is the whole
recording; in a walk only the swing phases (see :mod:`.segments`). Each segment starts from the
recorded positions at its start, at rest.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from hexapod_model.description import Robot
from hexapod_model.dictionary import supply_resistance_ohm
from hexapod_model.joints import LEG_JOINTS, Joint, joint_names
from hexapod_model.servo import firmware_torque_nm, goal_joint_tick, theta_to_tick, tick_to_theta
from hexapod_model.swing_model import CoxaModel, LegModel, rollout_batch
from hexapod_sim.discrepancy.recording import Recording, RecordingError


@dataclass(frozen=True)
class JointReads:
    """The analysed reads of one joint: stamps [s], recorded ticks, and the segment of each read."""

    t_s: np.ndarray
    tick: np.ndarray
    segment: np.ndarray      # index into Replay.segments[leg]


class Replay:
    """Replays a recording through the model of any robot (nominal or with effects).

    ``segments``: optional dict leg -> list of (t_start, t_end) free-leg spans [s]; default one
    span over the whole recording for every leg. ``moving_start``: segments start in motion (a
    walk's swing, from lift-off): the initial state is a straight line through the reads within
    ``state_window_s`` of the start (position and velocity) instead of the latest read at rest.
    """

    def __init__(self, robot: Robot, rec: Recording, joints=None, segments=None, moving_start: bool = False,
                 state_window_s: float = 0.03):
        self.robot = robot
        # per joint, added to the prediction at each analysed read [ticks]: what a fuller replay of the
        # nominal robot adds to the free-leg model (the body's motion in a walk, .body_motion); None = nothing
        self.correction: dict[Joint, np.ndarray] | None = None
        self.moving_start = moving_start
        self.state_window_s = state_window_s
        self.rec = rec
        self.dt = robot.servo.control_period_s
        # each joint's bus entry (mounting direction and offset), for the goals the servos receive
        self.mount = {Joint.of(b.joint): b for b in robot.bus.joints}
        avail = rec.joints
        if joints is not None:
            unknown = [j for j in joints if j not in rec.states]
            if unknown:
                raise RecordingError(f'--joints {joint_names(unknown)}: not read in {rec.source} '
                                     f'(read: {joint_names(sorted(rec.states))})')
            uncmd = [j for j in joints if j not in rec.commands]
            if uncmd:
                raise RecordingError(f'--joints {joint_names(uncmd)}: never commanded in {rec.source}')
            avail = tuple(j for j in avail if j in set(joints))
        if not avail:
            raise RecordingError(f'{rec.source}: no joint is both commanded and read')
        self.legs = tuple(sorted({j.leg for j in avail}))
        t_end = rec.duration_s
        self.n_periods = int(math.ceil(t_end / self.dt)) + 2
        k = np.arange(self.n_periods)
        # goal per period for every joint of the analysed legs
        self.goals: dict[Joint, np.ndarray] = {}
        for leg in self.legs:
            for j in LEG_JOINTS[leg]:
                self.goals[j] = self._goals_per_period(j, k)
        # segments and analysed reads
        self.segments: dict[int, list[tuple[int, int]]] = {}
        for leg in self.legs:
            spans = (segments or {}).get(leg, [(0.0, t_end + self.dt)])
            segs = []
            for a, b in spans:
                ka = max(int(math.floor(a / self.dt + 1e-9)), 0)
                kb = min(int(math.ceil(b / self.dt - 1e-9)), self.n_periods - 1)
                if kb - ka >= 2:
                    segs.append((ka, kb))
            self.segments[leg] = segs
        self.reads: dict[Joint, JointReads] = {}
        for j in avail:
            s = rec.states[j]
            seg_of = np.full(len(s), -1)
            for i, (ka, kb) in enumerate(self.segments[j.leg]):
                m = (s.t_s >= ka * self.dt) & (s.t_s <= kb * self.dt)
                seg_of[m & (seg_of < 0)] = i
            keep = seg_of >= 0
            if np.any(keep):
                self.reads[j] = JointReads(s.t_s[keep], theta_to_tick(s.theta_rad[keep], robot.servo), seg_of[keep])
        self.joints = tuple(j for j in avail if j in self.reads)
        if not self.joints:
            raise RecordingError(f'{rec.source}: no read falls inside the analysed time spans')
        # initial state of every segment: the latest read at or before its start (else the first after)
        self.q0: dict[tuple[int, int], np.ndarray] = {}
        self.dq0: dict[tuple[int, int], np.ndarray] = {}
        for leg in self.legs:
            for i, (ka, _) in enumerate(self.segments[leg]):
                st = [self._moving_state_at(j, ka * self.dt) if moving_start
                      else (self._state_at(j, ka * self.dt), 0.0) for j in LEG_JOINTS[leg]]
                self.q0[(leg, i)] = np.array([x for x, _ in st])
                self.dq0[(leg, i)] = np.array([v for _, v in st])
        # coxa inertia pose per segment: median commanded femur/tibia while the coxa moves
        self.coxa_pose: dict[tuple[int, int], tuple[float, float]] = {}
        for leg in self.legs:
            gc, gf, gt = (self.goals[j] for j in LEG_JOINTS[leg])
            for i, (ka, kb) in enumerate(self.segments[leg]):
                moving = np.zeros(kb - ka, dtype=bool)
                moving[1:] = np.diff(gc[ka:kb]) != 0
                sel = moving if np.count_nonzero(moving) >= 5 else np.ones(kb - ka, dtype=bool)
                self.coxa_pose[(leg, i)] = (float(tick_to_theta(np.median(gf[ka:kb][sel]), robot.servo)),
                                            float(tick_to_theta(np.median(gt[ka:kb][sel]), robot.servo)))

    # ------------------------------------------------------------------ set-up helpers
    def _goals_per_period(self, j: Joint, k: np.ndarray) -> np.ndarray:
        cmd = self.rec.commands.get(j)
        hold = self._first_read_tick(j)
        if cmd is None or len(cmd) == 0:
            return np.full(len(k), hold)
        kc = np.ceil(cmd.t_s / self.dt - 1e-9).astype(np.int64)
        g = goal_joint_tick(cmd.theta_rad, self.robot.servo, self.mount[j])
        idx = np.searchsorted(kc, k, side='right') - 1
        out = np.where(idx >= 0, g[np.clip(idx, 0, None)], hold)
        return np.ascontiguousarray(out, dtype=np.float64)

    def _first_read_tick(self, j: Joint):
        s = self.rec.states.get(j)
        if s is None or len(s) == 0:
            cmd = self.rec.commands.get(j)
            if cmd is None or len(cmd) == 0:
                return float(self.robot.servo.center_tick)
            return float(goal_joint_tick(cmd.theta_rad[:1], self.robot.servo, self.mount[j])[0])
        return float(np.rint(theta_to_tick(s.theta_rad[0], self.robot.servo)))

    def _state_at(self, j: Joint, t: float) -> float:
        s = self.rec.states.get(j)
        if s is None or len(s) == 0:
            k = min(max(int(round(t / self.dt)), 0), self.n_periods - 1)
            return float(tick_to_theta(self.goals[j][k], self.robot.servo))
        i = int(np.searchsorted(s.t_s, t, side='right')) - 1
        return float(s.theta_rad[max(i, 0)])

    def _moving_state_at(self, j: Joint, t: float) -> tuple[float, float]:
        """(angle, velocity) at ``t``: least-squares line through the reads within the state window."""
        s = self.rec.states.get(j)
        if s is None or len(s) == 0:
            return self._state_at(j, t), 0.0
        lo, hi = np.searchsorted(s.t_s, [t - self.state_window_s, t + self.state_window_s])
        tt, q = s.t_s[lo:hi], s.theta_rad[lo:hi]
        if len(tt) < 2 or np.ptp(tt) < 1e-3:
            return self._state_at(j, t), 0.0
        slope, icpt = np.polyfit(tt - t, q, 1)
        return float(icpt), float(slope)

    # ------------------------------------------------------------------ prediction
    def rollout_leg(self, robot: Robot, leg: int, seg: int, which: str):
        """Rollout of one segment: ``which`` = 'ft' (femur+tibia) or 'coxa'. Returns (k0, q grid (n+1, 2))."""
        ka, kb = self.segments[leg][seg]
        q0 = self.q0[(leg, seg)]
        i_ext = self.other_current_a(leg, which)[ka:kb] if supply_resistance_ohm(robot) > 0 else None
        if which == 'ft':
            g = np.empty((kb - ka, 2))
            g[:, 0] = self.goals[Joint(leg, 'femur')][ka:kb]
            g[:, 1] = self.goals[Joint(leg, 'tibia')][ka:kb]
            ro = LegModel(robot, leg).rollout(q0[1:], self.dq0[(leg, seg)][1:], g, i_ext=i_ext)
            return ka, ro.q_rad
        ro = CoxaModel(robot, leg, self.coxa_pose[(leg, seg)]).rollout_coxa(
            q0[0], float(self.dq0[(leg, seg)][0]), self.goals[Joint(leg, 'coxa')][ka:kb], i_ext=i_ext)
        return ka, ro.q_rad

    def rollout_segments(self, robot: Robot, leg: int, which: str) -> list[tuple[int, np.ndarray]]:
        """:meth:`rollout_leg` of every segment of ``leg``, from one model: without dictionary terms the
        segments are rolled out together (:func:`~hexapod_model.swing_model.rollout_batch`)."""
        segs = range(len(self.segments[leg]))
        model = LegModel(robot, leg) if which == 'ft' else CoxaModel(robot, leg)
        if model.has_terms:
            return [self.rollout_leg(robot, leg, i, which) for i in segs]
        k0 = [self.segments[leg][i][0] for i in segs]
        if which == 'ft':
            params = np.repeat(model.params[None], len(segs), axis=0)
            q0 = np.array([self.q0[(leg, i)][1:] for i in segs]).reshape(-1, 2)
            qd0 = np.array([self.dq0[(leg, i)][1:] for i in segs]).reshape(-1, 2)
            gap0 = np.array([model.start_gap_rad(x) for x in q0]).reshape(-1, 2)
            gf, gt = self.goals[Joint(leg, 'femur')], self.goals[Joint(leg, 'tibia')]
            goals = [np.column_stack((gf[ka:kb], gt[ka:kb])) for ka, kb in self.segments[leg]]
        else:
            params = np.array([model.params_at(self.coxa_pose[(leg, i)]) for i in segs]).reshape(-1, len(model.params))
            q0 = np.array([(self.q0[(leg, i)][0], 0.0) for i in segs]).reshape(-1, 2)
            qd0 = np.array([(self.dq0[(leg, i)][0], 0.0) for i in segs]).reshape(-1, 2)
            gap0 = np.zeros((len(segs), 2))
            gc = self.goals[Joint(leg, 'coxa')]
            goals = [np.column_stack((gc[ka:kb], np.full(kb - ka, model.center_tick))) for ka, kb in self.segments[leg]]
        return list(zip(k0, rollout_batch(params, q0, qd0, goals, gap0)))

    def other_current_a(self, leg: int, which: str) -> np.ndarray:
        """Per firmware period, the stall current [A] the firmware of every other recorded servo asks for
        (``|torque(goal - latest read)| / (K R)`` of the nominal law), for a supply sag
        (:mod:`hexapod_model.dictionary`): the rest of the robot's draw on the supply, from the recording."""
        key = (leg, which)
        cache = self.__dict__.setdefault('_other_current', {})
        if key not in cache:
            s = self.robot.servo
            mine = {Joint(leg, 'coxa')} if which == 'coxa' else {Joint(leg, 'femur'), Joint(leg, 'tibia')}
            k = np.arange(self.n_periods)
            total = np.zeros(self.n_periods)
            for j, st in self.rec.states.items():
                if j in mine or j not in self.rec.commands or len(st) == 0:
                    continue
                goal = self.goals.get(j)
                goal = self._goals_per_period(j, k) if goal is None else goal
                idx = np.clip(np.searchsorted(st.t_s, k * self.dt, side='right') - 1, 0, len(st) - 1)
                present = np.rint(theta_to_tick(st.theta_rad[idx], s))
                total += np.abs(firmware_torque_nm(goal, present, s.gain_nm_per_tick, s.stall_torque_nm,
                                                   s.compliance_margin_ticks, s.punch_nm))
            cache[key] = total / (s.torque_constant_nm_per_a * s.gear_ratio)
        return cache[key]

    def predict_joints(self, robot: Robot, joints) -> dict[Joint, np.ndarray]:
        """Predicted (continuous) tick at every analysed read of ``joints`` for ``robot``."""
        out: dict[Joint, np.ndarray] = {}
        want = [j for j in joints if j in self.reads]
        legs = sorted({j.leg for j in want})
        for leg in legs:
            roles = {j.role for j in want if j.leg == leg}
            jobs = []
            if roles & {'femur', 'tibia'}:
                jobs.append(('ft', (('femur', 0), ('tibia', 1))))
            if 'coxa' in roles:
                jobs.append(('coxa', (('coxa', 0),)))
            for which, cols in jobs:
                per_seg = self.rollout_segments(robot, leg, which)
                for role, col in cols:
                    j = Joint(leg, role)
                    if j not in self.reads or role not in roles:
                        continue
                    out[j] = self.sample(robot, j, per_seg, col)
        return out

    def sample(self, robot: Robot, j: Joint, per_seg, col: int) -> np.ndarray:
        """Predicted ticks at the reads of ``j`` from per-segment rollouts (column ``col``), with its readout delay."""
        r = self.reads[j]
        e = robot.joint_effects(j)
        delay = e.readout_delay_s + e.goal_latency_s
        pred = np.empty(len(r.t_s))
        for i, (k0, q) in enumerate(per_seg):
            m = r.segment == i
            if not np.any(m):
                continue
            x = (r.t_s[m] - delay) / self.dt - k0
            x = np.clip(x, 0.0, len(q) - 1.0)
            i0 = np.minimum(np.floor(x).astype(np.int64), len(q) - 2)
            f = x - i0
            th = q[i0, col] * (1.0 - f) + q[i0 + 1, col] * f
            pred[m] = theta_to_tick(th, robot.servo)
        if self.correction is not None and j in self.correction:
            pred += self.correction[j]
        return pred

    def predict(self, robot: Robot) -> dict[Joint, np.ndarray]:
        return self.predict_joints(robot, self.joints)

    def residuals(self, pred: dict) -> dict[Joint, np.ndarray]:
        """Recorded minus predicted ticks (``pred``: joint -> ticks at the reads) of every replayed joint."""
        return {j: self.reads[j].tick - pred[j] for j in self.joints}

    def trajectory(self, robot: Robot, leg: int):
        """Full 1 kHz predicted trajectories of a leg (coxa, femur, tibia) for plots: (t_s, theta (n, 3)), NaN outside segments."""
        q = np.full((self.n_periods, 3), np.nan)
        for (ka, kb), (_, ft), (_, cx) in zip(self.segments[leg], self.rollout_segments(robot, leg, 'ft'),
                                              self.rollout_segments(robot, leg, 'coxa')):
            q[ka:kb + 1, 1:] = ft[: kb + 1 - ka]
            q[ka:kb + 1, 0] = cx[: kb + 1 - ka, 0]
        return np.arange(self.n_periods) * self.dt, q
