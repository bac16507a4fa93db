"""``sim_node``: the MuJoCo hexapod behind exactly the driver's ROS interface (hexapod_model.contract).

In: ``/joint_commands`` (sensor_msgs/JointState: goals, one sync write per message),
``/read_schedule`` (hexapod_msgs/ReadSchedule), services ``/set_read_schedule``
(hexapod_msgs/SetReadSchedule: the schedule, acknowledged once applied) and ``/emergency_stop``
(std_srvs/Trigger).
Out: ``/joint_states`` (one message per read, stamped with the sample time), ``/servo_diagnostics``,
``/bus_timing``, ``/diagnostics`` (every servo with each servo-diagnostics round, the bus with each
bus-timing window), ``/imu``, ``/power``, ``/clock`` and the evaluation-only truth
``/sim/foot_contacts`` and ``/sim/body_pose``. All stamps are simulated time.

Pacing: ``real_time_factor`` > 0 keeps simulated time at that multiple of wall time; 0 runs as fast
as possible. ``lockstep``: the simulation only advances by one cycle of the read schedule per
received ``/joint_commands`` message (a message with no names just advances), so a controller
that waits for its reads gets a deterministic run independent of machine load. A lock-stepped
controller sets the schedule through the service: a /read_schedule message can be taken after a
command published later (two topics are not ordered), and that command's cycle would then read
the old schedule.

``record``: '' (off), 'auto' (``bags/sim_<UTC time>``), a name (``bags/<name>``) or a path: every
topic above plus ``/ground_detection``, ``/swing_down`` and ``/cmd_vel`` is written to a rosbag2 MCAP bag,
with ``/robot_description``, ``/tf_static`` and ``/tf`` (hexapod_sim.bagio.recorder). The bag is written by
a process of its own (:class:`~hexapod_sim.bagio.recorder_process.RecorderProcess`; with the Foxglove live view, by a
thread of this node, :class:`~hexapod_sim.bagio.recorder.RecorderThread`): publishing and recording a message
only enqueues it, so neither the controller's bus transactions nor the executor's callbacks wait for
the bag, and the conversion and writing do not take this process's interpreter from the executor
thread that steps the sim and answers the bus; closing the node writes everything enqueued, then
closes the bag.

``/robot_description`` (std_msgs/String, transient local): the URDF of the description.
``foxglove:=true`` (``foxglove_port``, default 8765): a Foxglove WebSocket live view on 127.0.0.1
with what a bag would hold (hexapod_sim.node.live).
"""
from __future__ import annotations

import sys
import threading

from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseStamped, Twist
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import BatteryState, Imu, JointState
from std_msgs.msg import Float64MultiArray, MultiArrayDimension, String
from std_srvs.srv import Trigger

from hexapod_model import contract, diagnostics
from hexapod_model.contract import stamp_msg
from hexapod_model.description import ALL_JOINTS, DescriptionError
from hexapod_model.imu import ImuReading
from hexapod_model.node_params import EXIT_BAD_PARAMETER, NodeParams, node_help, run_node, spin_until_shutdown
from hexapod_model.param_schema import ReadTime, RobotSource
from hexapod_model.urdf import urdf_xml
from hexapod_msgs.msg import BusTiming, LegGroundDetection, ReadSchedule, ServoDiagnostics, ServoStatus, SwingDownStart, TerrainClass
from hexapod_msgs.srv import SetReadSchedule
from hexapod_sim.bagio import BagError
from hexapod_sim.bagio.recorder import Recorder, RecorderThread, resolve_bag_dir
from hexapod_sim.bagio.recorder_process import RecorderProcess
from hexapod_sim.node.bus_master_loop import (
    TRUTH_LAYOUT,
    BusTimingSample,
    ClockTick,
    JointSample,
    PowerSample,
    SimBusLoop,
    TruthSample,
    truth_vector,
)
from hexapod_sim.node.live import LiveView, LiveViewError
from hexapod_sim.node.local_bus import CommandSample, LocalSimBus, Pacer, ScheduleSample
from hexapod_sim.node.params import NODE, SimParams
from hexapod_sim.physics.plant import ERR_ANGLE_LIMIT, ERR_OVERHEATING, HexapodSim, SimError
from hexapod_sim.physics.readings import ServoTelemetry
from hexapod_sim.physics.scene_params import SceneParams
from hexapod_sim.physics.terrain import Ground
from hexapod_sim.physics.truth_log import TruthLog

TIMER_PERIOD_S = 0.002        # wall period of the stepping timer
MAX_READS_PER_TICK = 200      # bound one callback so subscriptions/services stay responsive
MAX_LAG_S = 0.5               # behind the real-time target by more than this: re-anchor, warn
QOS_DEPTH = 1000              # one message per read: deep queues so a loaded subscriber loses nothing


class SimNode(Node):
    def __init__(self, **node_kwargs):
        super().__init__('sim_node', **node_kwargs)
        params = NodeParams(self)
        robot = params.declare(RobotSource).load()
        scene = self.scene = params.declare(SceneParams)
        t_com_s = params.declare(ReadTime).t_com_s
        p = self.params = params.declare(SimParams)
        self.sim = HexapodSim(robot, terrain=scene.terrain, seed=scene.seed, t_com_s=t_com_s or robot.bus.t_com_s,
                              fixed_base=p.fixed_base,
                              t_write_s=p.t_write_s, imu_rate_hz=p.imu_rate_hz,
                              ambient_c=p.ambient_temperature_c, initial_temperature_c=p.initial_temperature_c,
                              start_xy_m=(scene.start_x_m, scene.start_y_m))     # SimError names what does not fit
        self.loop = SimBusLoop(self.sim, power_period_s=p.period(p.power_rate_hz),
                               diagnostics_period_s=p.period(p.diagnostics_rate_hz),
                               timing_period_s=p.period(p.bus_timing_rate_hz),
                               truth_period_s=p.period(p.truth_rate_hz), clock_period_s=p.period(p.clock_rate_hz),
                               truth_log=TruthLog(p.truth_out) if p.truth_out else None)
        self.pacer = Pacer(p.real_time_factor, self.sim.now, max_lag_s=MAX_LAG_S)
        params.on_change('real_time_factor', self.pacer.reanchor)
        self.lockstep = p.lockstep
        self._lock = threading.RLock()      # the sim and its loop: executor vs in-process controller
        self._local: LocalSimBus | None = None
        self._last_timing_t_s = 0.0         # start of the /bus_timing window (bus health on /diagnostics)
        self.recorder = None
        self.live = None
        self._stop_on_record_error = p.stop_on_record_error
        self.stopped_on_record_error = False     # the node ended on a failed write to the bag
        if p.foxglove:
            try:
                self.live = LiveView(p.foxglove_port, name='hexapod sim_node')
            except LiveViewError as exc:
                raise SystemExit(f'sim_node: {exc}') from None
            self.get_logger().info(f'Foxglove live view on {self.live.url}')
        if p.record or self.live is not None:     # the live view gets what a bag would hold
            path = resolve_bag_dir(p.record) if p.record else None
            scene_text = Ground(scene.terrain, scene.seed, (scene.start_x_m, scene.start_y_m)).to_text()
            if self.live is None:       # the bag alone: written by a process of its own
                self.recorder = RecorderProcess(path, robot=robot, on_error=self._recording_failed, scene=scene_text)
            else:                       # the live view serves from this process
                self.recorder = RecorderThread(Recorder(path, robot=robot, live=self.live, scene=scene_text),
                                               on_error=self._recording_failed)
            if path is not None:
                self.get_logger().info(f'recording to {path}')

        latched = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL)
        self._description_pub = self.create_publisher(String, contract.ROBOT_DESCRIPTION, latched)
        self._description_pub.publish(String(data=urdf_xml(robot)))
        qos = QoSProfile(depth=QOS_DEPTH)
        self.pub = {
            contract.JOINT_STATES: self.create_publisher(JointState, contract.JOINT_STATES, qos),
            contract.SERVO_DIAGNOSTICS: self.create_publisher(ServoDiagnostics, contract.SERVO_DIAGNOSTICS, 10),
            contract.BUS_TIMING: self.create_publisher(BusTiming, contract.BUS_TIMING, 10),
            contract.IMU: self.create_publisher(Imu, contract.IMU, 100),
            contract.POWER: self.create_publisher(BatteryState, contract.POWER, 100),
            contract.CLOCK: self.create_publisher(Clock, contract.CLOCK, 100),
            contract.SIM_TRUTH_CONTACTS: self.create_publisher(Float64MultiArray, contract.SIM_TRUTH_CONTACTS, 100),
            contract.SIM_TRUTH_POSE: self.create_publisher(PoseStamped, contract.SIM_TRUTH_POSE, 100),
            contract.DIAGNOSTICS: self.create_publisher(DiagnosticArray, contract.DIAGNOSTICS, 10),
        }
        self._cmd_sub = self.create_subscription(JointState, contract.JOINT_COMMANDS, self._on_command, qos)
        self._sched_sub = self.create_subscription(ReadSchedule, contract.READ_SCHEDULE, self._on_schedule, 10)
        self.create_service(SetReadSchedule, contract.SET_READ_SCHEDULE, self._on_set_schedule)
        self._recorded_subs = []          # (subscription, topic): the controller's topics in the bag
        if self.recorder is not None:     # record the controller's topics too
            from nav_msgs.msg import Odometry
            for msg_type, topic, depth in ((LegGroundDetection, contract.GROUND_DETECTION, QOS_DEPTH),
                                           (SwingDownStart, contract.SWING_DOWN, 100), (Twist, contract.CMD_VEL, 10),
                                           (Odometry, contract.ODOM, 100), (TerrainClass, contract.TERRAIN, 10)):
                sub = self.create_subscription(msg_type, topic, lambda m, t=topic: self._record(t, m, self.sim.now()),
                                               depth)
                self._recorded_subs.append((sub, topic))
        self.create_service(Trigger, contract.EMERGENCY_STOP, self._on_estop)
        # lock-step advances in _on_command only: a timer would just wake the executor 500 times a second
        self._timer = None if self.lockstep else self.create_timer(TIMER_PERIOD_S, self._on_timer)
        self._anchored = False         # simulated time starts with the first tick, not during set-up
        self.get_logger().info(
            f'sim ready: terrain={scene.terrain} seed={scene.seed} t_com={self.sim.t_com_s * 1e3:g} ms '
            f'{"lockstep" if self.lockstep else f"real_time_factor={self.pacer.rtf:g}"} '
            f'effects={len(robot.effects)}')

    # ------------------------------------------------------------------ in-process controller
    def local_bus(self) -> LocalSimBus:
        """The bus for a controller composed into this process (``hexapod_locomotion robot``).

        The controller then owns the bus as it would on the robot: it reads and writes in its own
        thread at Algorithm 1's cadence, and this node publishes and records every transaction
        (``/joint_commands`` included) instead of taking commands or schedules from the graph.
        """
        if self.lockstep:
            raise SimError('lockstep:=true and an in-process controller exclude each other '
                           '(lock-step is for a controller in another process; in-process, use real_time_factor:=0)')
        if self._local is None:
            # the controller's thread steps the bus from now on (background reads included): a 2 ms
            # timer would only take the interpreter from it
            self.destroy_timer(self._timer)
            self.destroy_subscription(self._cmd_sub)
            self.destroy_subscription(self._sched_sub)
            self.pub[contract.JOINT_COMMANDS] = self.create_publisher(
                JointState, contract.JOINT_COMMANDS, QoSProfile(depth=QOS_DEPTH))
            self._local = LocalSimBus(self.loop, self._emit, self.pacer, self._lock, on_lag=self._warn_lag)
        return self._local

    def _emit(self, events) -> None:
        for ev in events:
            self._publish(ev)

    def _warn_lag(self, behind_s: float) -> None:
        self.get_logger().warn(f'cannot keep real_time_factor={self.pacer.rtf:g} ({behind_s:.2f} s behind): '
                               'running as fast as possible', throttle_duration_sec=10.0)

    # ------------------------------------------------------------------ inputs
    def _on_command(self, msg: JointState) -> None:
        with self._lock:
            self._command(msg)

    def _command(self, msg: JointState) -> None:
        self._record(contract.JOINT_COMMANDS, msg, self.sim.now())
        if len(msg.name) != len(msg.position):
            self.get_logger().error(f'/joint_commands ignored: {len(msg.name)} names but {len(msg.position)} positions')
        else:
            try:
                self.loop.command(dict(zip(msg.name, msg.position)))
            except SimError as exc:
                self.get_logger().error(f'/joint_commands ignored: {exc}')
        if self.lockstep:               # one cycle of the read schedule per command, right now
            for ev in self.loop.run(max_reads=self.loop.cycle_reads):
                self._publish(ev)

    def _on_schedule(self, msg: ReadSchedule) -> None:
        self._apply_schedule(msg, '/read_schedule')

    def _on_set_schedule(self, request, response):
        if self._local is not None:
            response.success = False
            response.message = 'the read schedule belongs to the controller running in this process'
            return response
        msg = ReadSchedule(joint_names=list(request.joint_names))
        msg.header.stamp = stamp_msg(self.sim.now())
        response.success, response.message = self._apply_schedule(msg, contract.SET_READ_SCHEDULE)
        return response

    def _apply_schedule(self, msg: ReadSchedule, via: str) -> tuple[bool, str]:
        """Set the read schedule; the bag records it as a /read_schedule message either way."""
        with self._lock:
            self._record(contract.READ_SCHEDULE, msg, self.sim.now())
            try:
                self.loop.set_schedule(list(msg.joint_names))
            except SimError as exc:
                self.get_logger().error(f'{via} ignored: {exc}')
                return False, str(exc)
            return True, 'reading ' + ', '.join(self.loop.schedule)

    def _on_estop(self, request, response):
        with self._lock:
            self.sim.emergency_stop()
        self.get_logger().warn('emergency stop: torque off on every servo')
        response.success = True
        response.message = f'torque off on all {len(ALL_JOINTS)} servos at t={self.sim.now():.3f} s (sim time)'
        return response

    # ------------------------------------------------------------------ stepping
    def _take_pending(self) -> None:
        """Apply every /joint_commands message that has arrived, before the sim steps on, and record
        every message of the controller's topics that has arrived.

        The executor takes one message per subscription per turn of its loop, after the timers: on
        a loaded machine each turn carries a long catch-up step, goals queued behind one another
        and took effect up to 0.4 s after the controller wrote them (and later still with the
        recording's subscriptions in the same executor), so Algorithm 1's model, which has each
        goal act when written, no longer held and free legs stopped in the air; and
        /ground_detection (up to 660 messages a second) overflowed its queue, so the bag lacked
        reads that ``analyse`` needs to replay the decisions."""
        for msg in _pending(self._cmd_sub):
            self._command(msg)
        for sub, topic in self._recorded_subs:
            for msg in _pending(sub):
                self._record(topic, msg, self.sim.now())

    def _on_timer(self) -> None:
        with self._lock:
            self._take_pending()
            if not self._anchored:
                self._anchored = True
                self.pacer.reanchor()
            target = self.pacer.target()
            if target is not None and target - self.sim.now() > MAX_LAG_S:
                self._warn_lag(target - self.sim.now())
                self.pacer.reanchor()
                target = self.pacer.target()
            self._emit(self.loop.run(until_s=target, max_reads=MAX_READS_PER_TICK))

    # ------------------------------------------------------------------ outputs
    def _record(self, topic: str, msg, t_s: float) -> None:
        """Hand ``msg`` to the bag's writer thread (no lock: executor callbacks must not wait for the bus)."""
        rec = self.recorder
        if rec is not None:
            rec.write(topic, contract.MSG_TYPES.get(topic) or _type_name(msg), msg, t_s)

    def _recording_failed(self, text: str) -> None:
        """The writer thread could not write (disk full, ...): one line; the robot runs on, unrecorded
        (the closing line at :meth:`close` then says how many messages the bag holds)."""
        if self._stop_on_record_error:
            self._stop_for_recording(text)
            return
        line = f'recording stopped: {text}; the simulation runs on without recording'
        if self.context.ok():
            self.get_logger().error(line)
        else:
            print(f'[sim_node] {line}', file=sys.stderr, flush=True)

    def _stop_for_recording(self, text: str) -> None:
        """``stop_on_record_error``: torque off on every servo, one line, and the node ends (exit code 1)."""
        with self._lock:
            self.sim.emergency_stop()
            t = self.sim.now()
        self.stopped_on_record_error = True
        line = (f'recording stopped: {text}; stopping (stop_on_record_error): torque off on every servo at '
                f't={t:.3f} s (sim time), the node ends')
        if self.context.ok():
            self.get_logger().error(line)
            self.context.try_shutdown()
        else:
            print(f'[sim_node] {line}', file=sys.stderr, flush=True)

    def _send(self, topic: str, msg, t_s: float) -> None:
        self.pub[topic].publish(msg)
        self._record(topic, msg, t_s)

    def _publish(self, ev) -> None:
        """Publish (and record) one event of the sim by its type (:attr:`_PUBLISHERS`); other events are dropped."""
        publish = self._PUBLISHERS.get(type(ev))
        if publish is not None:
            publish(self, ev)

    def _publish_joint(self, ev: JointSample) -> None:
        m = JointState()
        m.header.stamp = stamp_msg(ev.t_s)
        m.name = [ev.joint]
        m.position = [ev.theta_rad]
        self._send(contract.JOINT_STATES, m, ev.t_s + self.sim.t_com_s)

    def _publish_command(self, ev: CommandSample) -> None:
        m = JointState()
        m.header.stamp = stamp_msg(ev.t_s)
        m.name = list(ev.goals_rad)
        m.position = [float(v) for v in ev.goals_rad.values()]
        self._send(contract.JOINT_COMMANDS, m, ev.t_s)

    def _publish_schedule(self, ev: ScheduleSample) -> None:
        m = ReadSchedule(joint_names=list(ev.joint_names))
        m.header.stamp = stamp_msg(ev.t_s)
        self._record(contract.READ_SCHEDULE, m, ev.t_s)

    def _publish_clock(self, ev: ClockTick) -> None:
        self._send(contract.CLOCK, Clock(clock=stamp_msg(ev.t_s)), ev.t_s)

    def _publish_imu(self, ev: ImuReading) -> None:
        m = Imu()
        m.header.stamp = stamp_msg(ev.t_s)
        m.header.frame_id = 'trunk'
        w, x, y, z = (float(v) for v in ev.quat_wxyz)
        m.orientation.w, m.orientation.x, m.orientation.y, m.orientation.z = w, x, y, z
        m.angular_velocity.x, m.angular_velocity.y, m.angular_velocity.z = (float(v) for v in ev.gyro)
        m.linear_acceleration.x, m.linear_acceleration.y, m.linear_acceleration.z = (
            float(v) for v in ev.accel)
        self._send(contract.IMU, m, ev.t_s)

    def _publish_power(self, ev: PowerSample) -> None:
        m = BatteryState()
        m.header.stamp = stamp_msg(ev.t_s)
        m.voltage = float(ev.voltage_v)
        m.current = -float(ev.current_a)          # sensor_msgs convention: negative when discharging
        nan = float('nan')
        m.charge = m.capacity = m.design_capacity = m.percentage = m.temperature = nan
        m.power_supply_status = BatteryState.POWER_SUPPLY_STATUS_DISCHARGING
        m.present = True
        self._send(contract.POWER, m, ev.t_s)

    def _publish_servos(self, ev: ServoTelemetry) -> None:
        m = ServoDiagnostics()
        m.header.stamp = stamp_msg(ev.t_s)
        ids = self.sim.servo_ids
        for i, name in enumerate(ALL_JOINTS):
            s = ServoStatus()
            s.joint_name = name
            s.id = int(ids[i])
            s.temperature_c = float(ev.temperature_c[i])
            s.voltage_v = float(ev.voltage_v[i])
            s.load_fraction = float(ev.load_fraction[i])
            s.error_bits = int(ev.error_bits[i])
            s.responding = True
            s.torque_enabled = bool(ev.torque_enabled[i])
            s.message = _error_text(int(ev.error_bits[i]), bool(ev.torque_enabled[i]))
            m.servos.append(s)
        self._send(contract.SERVO_DIAGNOSTICS, m, ev.t_s)
        self._diagnostics([diagnostics.servo_status(
            self.sim.robot, self.get_name(), name, int(ids[i]), temperature_c=float(ev.temperature_c[i]),
            voltage_v=float(ev.voltage_v[i]), load_fraction=float(ev.load_fraction[i]),
            error_bits=int(ev.error_bits[i]), responding=True, torque_enabled=bool(ev.torque_enabled[i]),
            torque_limit=None) for i, name in enumerate(ALL_JOINTS)], ev.t_s)

    def _publish_bus_timing(self, ev: BusTimingSample) -> None:
        m = BusTiming()
        m.header.stamp = stamp_msg(ev.t_s)
        m.reads = ev.reads
        m.failed_reads = 0
        m.t_com_mean_s = m.t_com_p99_s = m.t_com_max_s = float(ev.t_com_s)
        m.write_mean_s = float(ev.t_write_s)
        self._send(contract.BUS_TIMING, m, ev.t_s)
        window = ev.t_s - self._last_timing_t_s
        self._last_timing_t_s = ev.t_s
        t_com = float(ev.t_com_s)
        self._diagnostics([diagnostics.bus_status(
            self.sim.robot, self.get_name(), window_s=window, reads=ev.reads, failed_reads=0, t_com_mean_s=t_com,
            t_com_p99_s=t_com, t_com_max_s=t_com, write_mean_s=float(ev.t_write_s))], ev.t_s)

    def _publish_truth(self, ev: TruthSample) -> None:
        m = Float64MultiArray()
        m.layout.dim = [MultiArrayDimension(label=lab, size=n, stride=n) for lab, n in TRUTH_LAYOUT]
        m.data = truth_vector(ev.contacts)
        self._send(contract.SIM_TRUTH_CONTACTS, m, ev.t_s)
        p = PoseStamped()
        p.header.stamp = stamp_msg(ev.t_s)
        p.header.frame_id = 'world'
        p.pose.position.x, p.pose.position.y, p.pose.position.z = (float(v) for v in ev.position_m)
        w, x, y, z = (float(v) for v in ev.quat_wxyz)
        p.pose.orientation.w, p.pose.orientation.x, p.pose.orientation.y, p.pose.orientation.z = w, x, y, z
        self._send(contract.SIM_TRUTH_POSE, p, ev.t_s)
        rec = self.recorder
        if rec is not None:                                 # TF of the truth in the bag, when due
            rec.write_tf_if_due(ev.t_s, ALL_JOINTS, ev.joint_angles_rad, (ev.position_m, ev.quat_wxyz))

    # the sim's events by type (none derives from another): what publishes each
    _PUBLISHERS = {JointSample: _publish_joint, CommandSample: _publish_command, ScheduleSample: _publish_schedule,
                   ClockTick: _publish_clock, ImuReading: _publish_imu, PowerSample: _publish_power,
                   ServoTelemetry: _publish_servos, BusTimingSample: _publish_bus_timing, TruthSample: _publish_truth}

    def _diagnostics(self, statuses, t_s: float) -> None:
        """/diagnostics (simulated time stamps); recorded as plain data (the byte level field)."""
        self.pub[contract.DIAGNOSTICS].publish(diagnostics.diagnostic_array(statuses, stamp_msg(t_s)))
        rec = self.recorder
        if rec is not None:
            rec.write(contract.DIAGNOSTICS, contract.MSG_TYPES[contract.DIAGNOSTICS],
                      diagnostics.array_dict(statuses, t_s), t_s)

    def close(self) -> None:
        """Finalise the bag (safe to call twice, also after the ROS context was shut down)."""
        if self._local is not None:
            self._local.stopped.set()
        if self.loop.truth_log is not None:
            with self._lock:
                self.loop.truth_log.save()
            self.loop.truth_log = None
        if self.recorder is not None:
            with self._lock:                # no transaction in between: what was published is in the bag
                rec, self.recorder = self.recorder, None
            rec.close()                     # writes everything enqueued, then closes the bag
            if rec.path is not None:
                if rec.close_error is not None:     # the bag may lack its summary: readers may refuse it
                    level, text = 'error', (f'bag not closed cleanly: {rec.path}: {rec.close_error} '
                                            f'({rec.count} messages written)')
                elif rec.error is not None:         # the write error itself was logged when it happened
                    level, text = 'warn', (f'bag closed: {rec.path} ({rec.count} messages; recording had stopped '
                                           f'on the error above)')
                else:
                    level, text = 'info', f'bag closed: {rec.path} ({rec.count} messages)'
                if self.context.ok():               # one call site per severity (rclpy wants that)
                    if level == 'info':
                        self.get_logger().info(text)
                    elif level == 'warn':
                        self.get_logger().warning(text)
                    else:
                        self.get_logger().error(text)
                else:                                   # after Ctrl-C the logger's publisher is gone
                    print(f'[sim_node] {text}', file=sys.stderr, flush=True)
        if self.live is not None:
            self.live.close()
            self.live = None


def _pending(sub):
    """The messages waiting in ``sub``'s queue, taken now (what the executor would take one per turn)."""
    while True:
        with sub.handle:
            taken = sub.handle.take_message(sub.msg_type, sub.raw)
        if taken is None:
            return
        yield taken[0]


def _type_name(msg) -> str:
    mod = type(msg).__module__.split('.')
    return f'{mod[0]}/msg/{type(msg).__name__}'


def _error_text(bits: int, enabled: bool) -> str:
    parts = []
    if bits & ERR_OVERHEATING:
        parts.append('overheating: alarm shutdown')
    if bits & ERR_ANGLE_LIMIT:
        parts.append('goal outside the angle limits (clamped)')
    if not enabled:
        parts.append('torque off')
    return '; '.join(parts) or 'ok'


def _spin(node: SimNode) -> None:
    try:
        spin_until_shutdown(node)
    finally:        # the stop shut the context down: spinning may end with ExternalShutdownException
        if node.stopped_on_record_error:
            raise SystemExit(1)


def main(args=None) -> None:
    run_node('sim_node', SimNode, node_help('sim_node', __doc__, NODE.schemas), args,
             errors=(DescriptionError, SimError, BagError), error_exit=EXIT_BAD_PARAMETER, close=SimNode.close,
             spec=NODE, spin=_spin)


if __name__ == '__main__':
    main()
