"""Walk the simulated robot with the gait controller, lock-stepped and without ROS. No rclpy.

The controller drives :class:`hexapod_sim.physics.plant.HexapodSim` through :class:`ProbeBus`, a transparent
:class:`~hexapod_model.bus.ServoBus` wrapper that (a) samples evaluation-only truth (body pose,
battery energy, foot contacts, femur torques, IMU) for the metrics and (b) optionally records every
bus transaction and sensor stream to a rosbag2 MCAP bag per the recording contract. The controller
never sees the truth. Everything runs on simulated time, so a trial is deterministic for its seed.
"""
from __future__ import annotations

import math
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from hexapod_locomotion.core.controller import GaitController
from hexapod_locomotion.core.detector import DetectorConfig, ReadResult, SwingDownPhase, swing_start_fields
from hexapod_locomotion.core.gait import get_gait
from hexapod_locomotion.core.locomotion_params import LocomotionError, VelocityCommand
from hexapod_locomotion.core.metrics import (
    DetectionEvent,
    MetricsError,
    detection_quality,
    roll_pitch_yaw,
    swing_down_variances,
    walk_cost_of_transport,
)
from hexapod_locomotion.trials.trial_config import TrialConfig, detector_config, locomotion_params
from hexapod_model import diagnostics
from hexapod_model.bus import ServoBus
from hexapod_model.contract import (
    DIAGNOSTICS,
    GROUND_DETECTION,
    IMU,
    JOINT_COMMANDS,
    JOINT_STATES,
    MSG_TYPES,
    POWER,
    SERVO_DIAGNOSTICS,
    SIM_TRUTH_CONTACTS,
    SIM_TRUTH_POSE,
    SWING_DOWN,
    stamp_dict,
)
from hexapod_model.description import ALL_JOINTS, JOINT_ROLES, LEGS, Robot, joint_name, load_robot, parse_joint_name
from hexapod_model.kinematics import forward

GAITS = ('tripod', 'tetrapod', 'pentapod')     # the gaits the experiments walk
DETECTORS = ('fixed', 'adaptive')
FALL_TILT_RAD = 0.6          # roll or pitch beyond this counts as a fall
FALL_HEIGHT_M = 0.035        # trunk this close to the ground counts as a fall


def joint_state_msg(t_s: float, names, positions) -> dict:
    return {'header': {'stamp': stamp_dict(t_s)}, 'name': list(names), 'position': [float(p) for p in positions]}


class TimeLimitReached(Exception):
    """Raised by :class:`ProbeBus` once the simulated time passes its deadline (mid-phase)."""


class ProbeBus(ServoBus):
    """ServoBus wrapper around a HexapodSim: samples truth and records, transparently.

    With ``deadline_s`` set, the first bus call at or after that simulated time raises
    :class:`TimeLimitReached`: a time limit is honoured within one control period, not only
    between gait phases.
    """

    deadline_s: float = math.inf

    def __init__(self, sim, probe_period_s: float = 0.05, recorder=None, on_probe=None, real_time: bool = False,
                 clock=None):
        self.sim = sim
        self.clock = clock                 # a ClockFile kept at the sim time reached after every bus call, or None
        self._wall0 = (time.monotonic() - sim.now()) if real_time else None    # pace to wall time (live view)
        self.on_probe = on_probe
        self.t_com_s = sim.t_com_s
        self.recorder = recorder
        self.probe_period_s = probe_period_s
        self._next_probe = 0.0
        self.pose_t: list[float] = []
        self.pose_xyz: list[np.ndarray] = []
        self.pose_quat: list[np.ndarray] = []
        self.power_w: list[float] = []         # battery power, mean over each probe period (as /power)
        self.temps: list[np.ndarray] = []
        self.imu_t: list[float] = []
        self.imu_rpy: list[tuple] = []
        self.imu_acc_z: list[float] = []
        self.femur_reads: dict[int, list[tuple]] = {leg: [] for leg in LEGS}
        from hexapod_sim.physics.plant import PowerMeter
        self._power_meter = PowerMeter(sim)
        self.body_z: list[tuple[float, float]] = []      # (stamp, trunk z) at every femur read (truth)
        self.detector_reads: dict[int, list[ReadResult]] = {leg: [] for leg in LEGS}
        self._probe()

    # -- ServoBus
    def now(self) -> float:
        return self.sim.now()

    def _check_deadline(self) -> None:
        if self.sim.now() >= self.deadline_s - 1e-12:
            raise TimeLimitReached(self.deadline_s)

    def _clock_reached(self) -> None:
        """Keep the clock file (if any) at the sim time reached."""
        if self.clock is not None:
            self.clock.set(self.sim.now())

    def sync_write(self, goals_rad) -> float:
        self._check_deadline()
        t = self.sim.sync_write(goals_rad)
        self._clock_reached()
        if self.recorder is not None:
            self.recorder.write(JOINT_COMMANDS, MSG_TYPES[JOINT_COMMANDS],
                                joint_state_msg(t, goals_rad.keys(), goals_rad.values()), t)
        return t

    def read_position(self, joint: str):
        self._check_deadline()
        theta, stamp = self.sim.read_position(joint)
        self._clock_reached()
        leg, role = parse_joint_name(joint)
        if role == 'femur':
            c = self.sim.foot_contacts()
            tau = self.sim.applied_torque_nm()[ALL_JOINTS.index(joint)]
            self.femur_reads[leg].append((stamp, bool(c.in_contact[leg - 1]), float(tau),
                                          self.sim.true_joint_angles()[3 * (leg - 1):3 * leg].copy()))
            self.body_z.append((stamp, float(self.sim.body_pose()[0][2])))
        if self.recorder is not None:
            self.recorder.write(JOINT_STATES, MSG_TYPES[JOINT_STATES], joint_state_msg(stamp, [joint], [theta]), stamp)
        self._maybe_probe()
        return theta, stamp

    def wait_until(self, t: float) -> None:
        while self.sim.now() < t - 1e-12:
            self._check_deadline()
            step_to = min(t, self._next_probe) if self._next_probe > self.sim.now() else t
            self.sim.wait_until(min(step_to, self.deadline_s))
            self._clock_reached()
            self._maybe_probe()
        self._check_deadline()

    # -- truth sampling and recording of sensor streams
    def _maybe_probe(self) -> None:
        if self.sim.now() >= self._next_probe - 1e-12:
            self._probe()
        rec = self.recorder
        if rec is not None and rec.tf_due(self.sim.now()):     # TF of the sim's truth in the bag
            rec.write_tf(self.sim.now(), ALL_JOINTS, self.sim.true_joint_angles(), self.sim.body_pose())
            if self._wall0 is not None:                          # never ahead of the wall clock
                time.sleep(max(0.0, self._wall0 + self.sim.now() - time.monotonic()))

    def _probe(self) -> None:
        t = self.sim.now()
        self._next_probe = t + self.probe_period_s
        pos, quat = self.sim.body_pose()
        bat = self._power_meter.sample()
        self.pose_t.append(t)
        self.pose_xyz.append(pos)
        self.pose_quat.append(quat)
        self.power_w.append(bat.power_w)
        temps = self.sim.temperatures_c()
        self.temps.append(temps)
        if self.on_probe is not None:
            self.on_probe(self.sim)
        imu = self.sim.pop_imu_samples()
        for s in imu:
            self.imu_t.append(s.t_s)
            self.imu_rpy.append(roll_pitch_yaw(s.quat_wxyz))
            self.imu_acc_z.append(float(s.accel[2]))
        rec = self.recorder
        if rec is None:
            return
        for s in imu:
            w, x, y, z = (float(v) for v in s.quat_wxyz)
            rec.write(IMU, MSG_TYPES[IMU], {
                'header': {'stamp': stamp_dict(s.t_s), 'frame_id': 'trunk'},
                'orientation': {'x': x, 'y': y, 'z': z, 'w': w},
                'angular_velocity': dict(zip('xyz', (float(v) for v in s.gyro))),
                'linear_acceleration': dict(zip('xyz', (float(v) for v in s.accel)))}, s.t_s)
        rec.write(POWER, MSG_TYPES[POWER], {'header': {'stamp': stamp_dict(t)}, 'voltage': bat.voltage_v,
                                            'current': -bat.current_a, 'present': True,
                                            'temperature': float('nan'), 'charge': float('nan'),
                                            'capacity': float('nan'), 'design_capacity': float('nan'),
                                            'percentage': float('nan')}, t)
        rec.write(SIM_TRUTH_POSE, MSG_TYPES[SIM_TRUTH_POSE], {
            'header': {'stamp': stamp_dict(t), 'frame_id': 'world'},
            'pose': {'position': dict(zip('xyz', (float(v) for v in pos))),
                     'orientation': dict(zip('wxyz', (float(v) for v in quat)))}}, t)
        contacts = self.sim.foot_contacts()
        rec.write(SIM_TRUTH_CONTACTS, MSG_TYPES[SIM_TRUTH_CONTACTS], {
            'data': [float(v) for v in contacts.in_contact] + [float(v) for v in contacts.force_world_n[:, 2]]}, t)
        if len(self.pose_t) % max(1, int(round(1.0 / self.probe_period_s))) == 0:   # diagnostics at 1 Hz
            st = self.sim.servo_state()
            ids = self.sim.servo_ids
            rec.write(SERVO_DIAGNOSTICS, MSG_TYPES[SERVO_DIAGNOSTICS], {
                'header': {'stamp': stamp_dict(t)},
                'servos': [{'joint_name': j, 'id': int(ids[i]), 'temperature_c': float(st.temperature_c[i]),
                            'voltage_v': float(st.voltage_v[i]), 'load_fraction': float(st.load_fraction[i]),
                            'error_bits': int(st.error_bits[i]), 'responding': True,
                            'torque_enabled': bool(st.torque_enabled[i])} for i, j in enumerate(ALL_JOINTS)]}, t)
            rec.write(DIAGNOSTICS, MSG_TYPES[DIAGNOSTICS], diagnostics.array_dict([diagnostics.servo_status(
                self.sim.robot, 'sim', j, int(ids[i]), temperature_c=float(st.temperature_c[i]),
                voltage_v=float(st.voltage_v[i]), load_fraction=float(st.load_fraction[i]),
                error_bits=int(st.error_bits[i]), responding=True, torque_enabled=bool(st.torque_enabled[i]))
                for i, j in enumerate(ALL_JOINTS)], t), t)

    def record_swing_start(self, phase: SwingDownPhase) -> None:
        if self.recorder is None:
            return
        self.recorder.write(SWING_DOWN, MSG_TYPES[SWING_DOWN],
                            {'header': {'stamp': stamp_dict(phase.t_start_s)}, **swing_start_fields(phase)}, phase.t_start_s)

    def record_detection(self, r: ReadResult) -> None:
        self.detector_reads[r.leg].append(r)
        if self.recorder is None:
            return
        self.recorder.write(GROUND_DETECTION, MSG_TYPES[GROUND_DETECTION], {
            'header': {'stamp': stamp_dict(r.stamp_s), 'frame_id': joint_name(r.leg, 'femur')},
            'leg': r.leg, 'detector': r.detector, 'swing_start': stamp_dict(r.stamp_s - r.t_swing_s),
            't_swing_s': r.t_swing_s, 'theta_des_tick': r.theta_des_tick, 'theta_real_tick': r.theta_real_tick,
            'theta_est_tick': r.theta_est_tick, 'err_tick': r.err_tick, 'err_est_tick': r.err_est_tick,
            'threshold_tick': r.threshold_tick, 'stopped': r.stopped, 'stop_reason': r.stop_reason}, r.stamp_s)


@dataclass
class TrialResult:
    config: dict
    sim_time_s: float                   # walking time (after the stand-up)
    walk_start_s: float                 # simulated time at which the walk began (the first gait phase)
    distance_m: float                   # net progress along x
    path_length_m: float                # length of the trunk's path (turning walks)
    fell: bool
    reached_course_end: bool
    phases: int                         # swing-down phases finished (every leg of the group stopped)
    cot: dict | None
    detection: dict | None
    stability: list[dict]
    temperature_femur_c: list[float]
    temperature_tibia_c: list[float]
    temperature_t_s: list[float]
    warnings: list[str] = field(default_factory=list)
    events: list[dict] = field(default_factory=list)
    odometry: dict | None = None        # per odometry ('imu', 'legs'): drift against the truth (odometry_trial.drift)

    def to_dict(self) -> dict:
        return asdict(self)


def body_rise_m(body_z, t0_s: float, t1_s: float) -> float:
    """Largest rise of the trunk (truth z at the femur reads) over its height at ``t0_s``, within [t0, t1]."""
    z = [v for t, v in body_z if t0_s - 1e-9 <= t <= t1_s + 1e-9]
    return float(max(z) - z[0]) if z else math.nan


def _detection_events(robot: Robot, probe: ProbeBus, phase: SwingDownPhase,
                      detector: DetectorConfig) -> list[DetectionEvent]:
    """Simulation truth for each leg of a finished swing-down (every leg has stopped)."""
    out = []
    t_con = len(phase.legs) * probe.t_com_s
    t0 = phase.t_start_s
    goals = phase.goals(0)          # all legs stopped: the frozen goals, whatever the step
    rise = body_rise_m(probe.body_z, t0, max(phase.state[leg].stop_time_s for leg in phase.legs))
    for leg in phase.legs:
        st = phase.state[leg]
        t_stop = st.stop_time_s
        reads = [r for r in probe.femur_reads[leg] if t0 - 1e-9 <= r[0] <= t_stop + 0.1]
        in_swing = [r for r in reads if r[0] <= t_stop + 1e-9]
        t_contact = next((r[0] for r in in_swing if r[1]), math.nan)
        at_stop = in_swing[-1] if in_swing else None
        # torque from the first true contact until shortly after the stop (the swing's own start-up
        # acceleration is not a contact load)
        peak = max((abs(r[2]) for r in reads if math.isfinite(t_contact) and r[0] >= t_contact), default=math.nan)
        overshoot = math.nan
        if at_stop is not None:       # the goal the leg was left at when it stopped vs where it truly was
            goal = [goals[joint_name(leg, r)] for r in JOINT_ROLES]
            overshoot = float(forward(robot, leg, at_stop[3])[2] - forward(robot, leg, goal)[2])
        # the floor: from the detector's margin (threshold - error) at the first read in contact, the
        # fewest control periods in which even a rigidly blocked leg, whose error grows by one goal
        # step per period, crosses the threshold (adaptive: about epsilon / step)
        floor = math.nan
        step = phase.femur_step_tick(leg, max(st.stop_step, 0))
        first = next((r for r in probe.detector_reads[leg] if math.isfinite(t_contact)
                      and t_contact - 1e-9 <= r.stamp_s <= t_stop + 1e-9), None)
        if first is not None and step > 0:
            floor = max(0.0, first.threshold_tick - first.err_tick) / step
        out.append(DetectionEvent(leg, detector.detector, t0, t_stop, st.stop_reason, t_contact,
                                  t_con, at_stop[2] if at_stop else math.nan, peak, overshoot, floor, rise))
    return out


def _recording_failed(text: str) -> None:
    """A write to the bag failed (disk full, ...): one line; the walk runs on, unrecorded."""
    import sys
    print(f'recording stopped: {text}; the walk runs on without recording', file=sys.stderr, flush=True)


def _open_recorder(cfg: TrialConfig, robot: Robot, ground, live, recorder):
    """Where the trial's topics go: the caller's ``recorder`` (in process), a recorder feeding the
    ``live`` view (and ``cfg.record``, if set), a recorder process writing ``cfg.record``, or None."""
    if recorder is None and live is not None:       # (a recorder given by the caller takes all, in process)
        from hexapod_sim.bagio.recorder import Recorder
        return Recorder(Path(cfg.record) if cfg.record else None, robot=robot, live=live, scene=ground.to_text())
    if recorder is None and cfg.record:   # by a process of its own, which closes the bag even if this one is killed
        from hexapod_sim.bagio.recorder_process import RecorderProcess
        return RecorderProcess(Path(cfg.record), robot=robot, on_error=_recording_failed, scene=ground.to_text())
    return recorder


def check_video(cfg: TrialConfig) -> None:
    """Raise :class:`~hexapod_sim.tools.render.RenderError` when the GIF of a walk of ``cfg.duration_s``
    would not fit in memory (:func:`~hexapod_sim.tools.render.check_video_memory`)."""
    from hexapod_sim.tools.render import check_video_memory
    check_video_memory(cfg.duration_s, cfg.video_fps, _Video.WIDTH, _Video.HEIGHT)


class _Video:
    """The frames of ``cfg.video``: one rendered every 1 / video_fps s of the truth probes."""

    WIDTH, HEIGHT = 480, 300       # pixels of a frame

    def __init__(self, cfg: TrialConfig, sim):
        import mujoco
        self.cfg = cfg
        self.frames = []
        self.renderer = mujoco.Renderer(sim.model, height=self.HEIGHT, width=self.WIDTH)
        self.every = max(1, int(round(1.0 / (cfg.video_fps * cfg.probe_period_s))))
        self.count = 0

    def on_probe(self, s) -> None:
        from PIL import Image

        from hexapod_sim.tools.render import render_frame
        if self.count % self.every == 0:
            self.frames.append(Image.fromarray(render_frame(s, self.renderer, distance=0.8, azimuth=120.0)))
        self.count += 1

    def close(self, on_video_write=None) -> None:
        """Free the renderer and write the GIF (if any frame was taken)."""
        self.renderer.close()
        frames = self.frames
        if frames:
            if on_video_write is not None:
                on_video_write(len(frames))
            Path(self.cfg.video).parent.mkdir(parents=True, exist_ok=True)
            frames[0].save(self.cfg.video, save_all=True, append_images=frames[1:], loop=0,
                           duration=int(round(1000 / self.cfg.video_fps)))


@dataclass
class _Walk:
    """How a walk went: where and when it began, how it ended, what the controller said."""

    walk_start_s: float = math.nan
    x0_m: float = math.nan
    fell: bool = False
    reached: bool = False
    warnings: list[str] = field(default_factory=list)


def _walk(cfg: TrialConfig, sim, probe: ProbeBus, controller: GaitController, odo, swing_downs, walk: _Walk,
          progress=None) -> None:
    """Stand up, then step gait phases until the time limit, the course end or a fall (into ``walk``)."""
    from hexapod_locomotion.core.course import CourseKeeper
    keeper = CourseKeeper.for_gait(controller.gait) if cfg.heading_correction else None
    warnings = walk.warnings
    controller.startup(probe)
    x0 = walk.x0_m = float(probe.pose_xyz[-1][0])
    walk_start = walk.walk_start_s = sim.now()
    probe.deadline_s = walk_start + cfg.duration_s
    while sim.now() - walk_start < cfg.duration_s:
        cmd = VelocityCommand(cfg.vx_mps, 0.0, cfg.wz_rad_s)
        est = odo.tap.estimate
        if keeper is not None and est is not None:
            p, gait = controller.params, controller.gait
            cmd = keeper.command(sim.now(), cmd, est.position[:2], float(est.rpy[2]), p.cycle_s(gait),
                                 p.saturating_velocity(gait)[0])
        try:
            rep = controller.step_phase(odo.tap, cmd)
            odo.tap.phase_done()
        except LocomotionError as exc:
            warnings.append(f'controller stopped: {exc}')
            return
        except TimeLimitReached:
            warnings.append(f'time limit {cfg.duration_s:g} s reached within a gait phase'
                            + ('' if swing_downs and swing_downs[-1].done else
                               '; its swing-down is not counted'))
            return
        warnings.extend(rep.warnings)
        pos, quat = sim.body_pose()
        roll, pitch, _ = roll_pitch_yaw(quat)
        clearance = pos[2] - sim.scene.terrain.height_at(pos[0], pos[1])
        if abs(roll) > FALL_TILT_RAD or abs(pitch) > FALL_TILT_RAD or clearance < FALL_HEIGHT_M:
            walk.fell = True
            warnings.append(f'robot fell at t={sim.now():.1f} s (roll {roll:.2f}, pitch {pitch:.2f} rad)')
            return
        if progress is not None:
            progress(sim.now() - walk_start, float(pos[0]) - x0)
        if cfg.course_end_m is not None and pos[0] >= cfg.course_end_m:
            walk.reached = True
            return


def run_trial(cfg: TrialConfig, progress=None, on_video_write=None, live=None, recorder=None,
              clock=None) -> TrialResult:
    """Walk one trial; ``progress(sim_time_s, distance_m)`` is called after every phase,
    ``on_video_write(n_frames)`` before the GIF is written. ``live``: a
    :class:`hexapod_sim.node.live.LiveView` that gets every recorded topic as it happens (the walk is
    then paced to real time). ``recorder``: an object with the methods of
    :class:`hexapod_sim.bagio.recorder.Recorder` that gets every recorded topic in process instead of a bag
    (``cfg.record`` and ``live`` then unused). ``clock``: a :class:`hexapod_sim.bagio.clock_file.ClockFile`
    kept at the sim time reached (the kill bench's clock for the demo).

    The walk ends at ``cfg.duration_s`` of simulated walking time within one control period (the
    phase in progress is cut off and not counted), at the course end, or when the robot falls."""
    from hexapod_sim.physics.plant import HexapodSim
    from hexapod_sim.physics.terrain import Ground
    if cfg.video:
        check_video(cfg)
    robot = load_robot(overlays=cfg.overlays)
    ground = Ground(cfg.terrain, cfg.seed, (cfg.start_x_m, cfg.start_y_m))
    sim = HexapodSim(robot, terrain=ground.terrain, seed=ground.seed, t_com_s=cfg.t_com_s or None,
                     start_xy_m=ground.start_xy_m)
    recorder = _open_recorder(cfg, robot, ground, live, recorder)
    video = _Video(cfg, sim) if cfg.video else None
    probe = ProbeBus(sim, cfg.probe_period_s, recorder, video.on_probe if video else None, real_time=live is not None,
                     clock=clock)
    swing_downs: list[SwingDownPhase] = []

    def on_swing_start(phase):
        swing_downs.append(phase)
        probe.record_swing_start(phase)
    det = detector_config(cfg)
    controller = GaitController(robot, get_gait(cfg.gait), locomotion_params(cfg), det, t_com_s=sim.t_com_s,
                                on_read=probe.record_detection, on_swing_start=on_swing_start)
    from hexapod_locomotion.trials.odometry_trial import TrialOdometry
    odo = TrialOdometry(probe, robot, controller, imu_first=cfg.odometry_imu, recorder=recorder)
    walk = _Walk()
    try:
        _walk(cfg, sim, probe, controller, odo, swing_downs, walk, progress)
    finally:
        probe.deadline_s = math.inf
        if recorder is not None:
            recorder.close()
            if getattr(recorder, 'close_error', None):
                _recording_failed(f'the bag could not be closed: {recorder.close_error}')
        if video is not None:
            video.close(on_video_write)
    return _result(cfg, robot, sim, probe, controller, odo, swing_downs, det, walk)


def trial_job(cfg: TrialConfig) -> dict:
    """One trial as a job of :func:`hexapod_locomotion.trials.executor.map_jobs`: its result as a dict."""
    return run_trial(cfg).to_dict()


def _result(cfg: TrialConfig, robot: Robot, sim, probe: ProbeBus, controller: GaitController, odo, swing_downs,
            det: DetectorConfig, walk: _Walk) -> TrialResult:
    """The figures of a finished walk, from the truth the probe sampled."""
    warnings, walk_start = walk.warnings, walk.walk_start_s
    t = np.array(probe.pose_t)
    xyz = np.array(probe.pose_xyz)
    walking = t >= walk_start - 1e-9
    finished = [ph for ph in swing_downs if ph.done]      # a swing-down cut off by the time limit is not counted
    events = [e for ph in finished for e in _detection_events(robot, probe, ph, det)]
    try:
        if not swing_downs:
            raise MetricsError('no swing-down')
        cot = walk_cost_of_transport(t, xyz[:, :2], t, probe.power_w, swing_downs[0].t_start_s,
                                     robot.total_mass_kg, robot.gravity_mps2)
    except MetricsError as exc:
        cot = None
        warnings.append(f'CoT not computed: {exc}')
    try:
        detection = detection_quality(events)
    except MetricsError:
        detection = None
    rpy = np.array(probe.imu_rpy) if probe.imu_rpy else np.zeros((0, 3))
    intervals = [(e.t_swing_start_s, e.t_stop_s, e.leg) for e in events]
    stability = swing_down_variances(np.array(probe.imu_t), rpy[:, 0] if len(rpy) else [], rpy[:, 1] if len(rpy) else [],
                                     np.array(probe.imu_acc_z), intervals) if len(rpy) else []
    temps = np.array(probe.temps)
    fem = [ALL_JOINTS.index(joint_name(leg, 'femur')) for leg in LEGS]
    tib = [ALL_JOINTS.index(joint_name(leg, 'tibia')) for leg in LEGS]
    step = max(1, int(round(1.0 / cfg.probe_period_s)))
    return TrialResult(
        config=asdict(cfg), sim_time_s=float(sim.now() - walk_start), walk_start_s=float(walk_start),
        distance_m=float(xyz[-1, 0] - walk.x0_m),
        path_length_m=float(np.sum(np.linalg.norm(np.diff(xyz[walking, :2], axis=0), axis=1))),
        fell=walk.fell, reached_course_end=walk.reached, phases=len(finished), cot=cot, detection=detection,
        stability=stability, temperature_femur_c=temps[::step, fem].mean(axis=1).tolist(),
        temperature_tibia_c=temps[::step, tib].mean(axis=1).tolist(), temperature_t_s=t[::step].tolist(),
        warnings=sorted(set(warnings)), events=[asdict(e) for e in events],
        odometry=odo.drift(t[walking], xyz[walking], np.array(probe.pose_quat)[walking],
                           controller.params.cycle_s(controller.gait)) if walking.sum() > 1 else None)
