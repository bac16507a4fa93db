"""locomotion_node: the adaptive gait cycle behind ROS topics.

Subscribes ``/cmd_vel`` and publishes per-read ground-detection telemetry on ``/ground_detection``
and each swing-down's inputs on ``/swing_down``. The controller (library code) runs in a worker
thread and talks to a servo bus:

* on its own (``ros2 run hexapod_locomotion locomotion_node``), through :class:`RosBus`: the servo
  interface of the driver or the sim node in another process (``/joint_states`` in,
  ``/joint_commands`` and the read schedule out; they are indistinguishable). Over DDS this cannot
  hold Algorithm 1's cadence in real time (docs/architecture.md); it is exact lock-stepped.
* composed with the driver or sim node in one process (``hexapod_locomotion robot``), through the
  bus object that node hands over: the controller then owns the bus as on the robot.

Leg odometry (:mod:`hexapod_locomotion.core.odometry`): the feet on the ground, from the forward kinematics
of the servo reads (the controller's and ``/joint_states``), fused with ``/imu`` when it is published,
give ``nav_msgs/Odometry`` on ``odom`` and the ``odom_frame -> base_frame`` transform on ``/tf`` (when
tf2_msgs is installed). With ``heading_correction`` the controller walks the commanded course
(:mod:`hexapod_locomotion.core.course`); without, the command as it is (the paper's open loop).

Whatever the route, each read the controller decides on is checked against Algorithm 1's timing
(:mod:`hexapod_locomotion.core.read_timing`): a read taken longer after the bus master published it
than the Eq. 17 margin allows, or sampled before the read taken just before it, is one warning
line at once (the first of each swing-down) and counted in ``/diagnostics``
(``locomotion_node: read timing``, published with every phase report and every warning).
"""
from __future__ import annotations

import gc
import math
import threading
import traceback

import rclpy
from rclpy._rclpy_pybind11 import RCLError
from rclpy.exceptions import InvalidHandle
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node

from hexapod_locomotion.core.controller import GaitController
from hexapod_locomotion.core.course import CourseChoice, CourseKeeper
from hexapod_locomotion.core.detector import DetectorConfig, DetectorError, swing_start_fields
from hexapod_locomotion.core.gait import GaitChoice, GaitError, get_gait
from hexapod_locomotion.core.locomotion_params import LocomotionError, LocomotionParams, VelocityCommand
from hexapod_locomotion.core.odometry import OdometryError
from hexapod_locomotion.core.odometry_tap import odometry_dict
from hexapod_locomotion.core.read_timing import ReadTiming
from hexapod_locomotion.nodes.params import NODE, LocomotionNodeParams
from hexapod_locomotion.nodes.ros_bus import RosBus
from hexapod_model import diagnostics
from hexapod_model.bus import BusError, ImuObserved, MasterClocked, ReadsObserved
from hexapod_model.contract import CMD_VEL, DIAGNOSTICS, GROUND_DETECTION, SWING_DOWN, stamp_msg, stamp_parts
from hexapod_model.description import ALL_JOINTS, DescriptionError, joint_name
from hexapod_model.node_params import NodeParams, node_help, run_node
from hexapod_model.param_schema import ReadTime, RobotSource


class LocomotionNode(Node):
    def __init__(self, bus=None, **node_kwargs):
        """``bus``: a :class:`hexapod_model.bus.ServoBus` that is also ``Scheduled`` and ``Stoppable``,
        owned by a node in this process; None = the bus over ROS topics."""
        super().__init__('locomotion_node', **node_kwargs)
        params = NodeParams(self)
        self.robot = params.declare(RobotSource).load()
        gait = params.declare(GaitChoice).gait
        # the ROS bus master keeps its own read schedule: no background reads of the controller's
        gait_params = params.declare(LocomotionParams, background_reads=False)
        detector = params.declare(DetectorConfig)
        t_com_s = params.declare(ReadTime).t_com_s
        course = params.declare(CourseChoice)
        p = self.params = params.declare(LocomotionNodeParams)
        if bus is not None:
            t_com = bus.t_com_s
            self.bus = bus
        else:
            t_com = t_com_s or self.robot.bus.t_com_s
            timeout = p.read_timeout_s or (10.0 if p.lockstep else 2.0)
            self.bus = RosBus(self, t_com, read_timeout_s=timeout, lockstep=p.lockstep)
        from geometry_msgs.msg import Twist

        from hexapod_msgs.msg import LegGroundDetection, SwingDownStart
        self._LGD = LegGroundDetection
        self._SDS = SwingDownStart
        from diagnostic_msgs.msg import DiagnosticArray
        # every read the controller decided on: a recording needs them all to replay the decisions
        self.det_pub = self.create_publisher(LegGroundDetection, GROUND_DETECTION, 1000)
        self.diag_pub = self.create_publisher(DiagnosticArray, DIAGNOSTICS, 10)
        self.timing = ReadTiming(self.get_name())
        self.swing_pub = self.create_publisher(SwingDownStart, SWING_DOWN, 10)
        self.create_subscription(Twist, CMD_VEL, self._on_cmd, 10)
        self._cmd = VelocityCommand(p.default_vx, 0.0, 0.0)
        self._cmd_time = None
        self.controller = GaitController(
            self.robot, get_gait(gait), gait_params, detector,
            t_com_s=t_com, on_read=self._publish_read, on_phase=self._log_phase,
            on_swing_start=self._publish_swing_start)
        self.controller.warm_up()
        self._setup_odometry(course.heading_correction)
        self._swing_start = {}
        self.failed = False
        self._worker = threading.Thread(target=self._run, daemon=True)
        self._worker.start()

    def _setup_odometry(self, heading_correction: bool) -> None:
        from geometry_msgs.msg import TransformStamped
        from nav_msgs.msg import Odometry
        from sensor_msgs.msg import Imu, JointState

        from hexapod_locomotion.core.odometry import LegOdometry
        from hexapod_locomotion.core.odometry_tap import OdometryTap
        from hexapod_model.contract import IMU, JOINT_STATES, ODOM, TF
        from hexapod_model.imu import ImuReading
        self._Odometry, self._ImuReading, self._TransformStamped = Odometry, ImuReading, TransformStamped
        self._imu = None
        self.odom_pub = self.create_publisher(Odometry, ODOM, 50)
        try:
            from tf2_msgs.msg import TFMessage
        except ImportError:            # the PyPI wheels have none; ./hexapod setup builds it where missing
            TFMessage = None
            self.get_logger().warning('tf2_msgs is not installed: odometry on /odom only, no /tf')
        self._TFMessage = TFMessage
        self.tf_pub = self.create_publisher(TFMessage, TF, 100) if TFMessage is not None else None
        self.tap = OdometryTap(self.bus, self.robot, self.controller.contact_legs, [(LegOdometry(), True)],
                               imu=lambda: self._imu, on_estimate=self._publish_odom)
        self.keeper = CourseKeeper.for_gait(self.controller.gait) if heading_correction else None
        if isinstance(self.bus, ImuObserved):       # the bus master's IMU in this process
            self.bus.observe_imu(self._take_imu)
        else:
            self.create_subscription(Imu, IMU, self._on_imu, 50)
        if isinstance(self.bus, ReadsObserved):     # every read the bus master makes, without a subscription
            self.bus.observe_reads(self.tap.observe)
        else:
            self.create_subscription(JointState, JOINT_STATES, self._on_joint_states, 500)

    def _on_imu(self, msg) -> None:
        q, w = msg.orientation, msg.angular_velocity
        quat = [q.w, q.x, q.y, q.z]
        # sensor_msgs/Imu: orientation covariance[0] = -1 means no orientation
        self._imu = self._ImuReading(quat_wxyz=None if msg.orientation_covariance[0] == -1 or not any(quat) else quat,
                                     gyro=[w.x, w.y, w.z])

    def _take_imu(self, reading) -> None:
        self._imu = reading

    def _on_joint_states(self, msg) -> None:
        if len(msg.name) == len(msg.position):
            self.tap.observe(msg.name, msg.position, msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9)

    def _publish_odom(self, e) -> None:
        p = self.params
        d = odometry_dict(e, p.odom_frame, p.base_frame)
        m = self._Odometry()
        m.header.stamp.sec, m.header.stamp.nanosec = stamp_parts(e.t_s)
        m.header.frame_id, m.child_frame_id = p.odom_frame, p.base_frame
        pose, twist = d['pose']['pose'], d['twist']['twist']
        for k in 'xyz':
            setattr(m.pose.pose.position, k, pose['position'][k])
            setattr(m.twist.twist.linear, k, twist['linear'][k])
            setattr(m.twist.twist.angular, k, twist['angular'][k])
        for k in 'xyzw':
            setattr(m.pose.pose.orientation, k, pose['orientation'][k])
        m.pose.covariance, m.twist.covariance = d['pose']['covariance'], d['twist']['covariance']
        self.odom_pub.publish(m)
        if self.tf_pub is not None:
            t = self._TransformStamped()
            t.header, t.child_frame_id = m.header, p.base_frame
            t.transform.translation.x, t.transform.translation.y, t.transform.translation.z = (
                float(v) for v in e.position)
            t.transform.rotation = m.pose.pose.orientation
            self.tf_pub.publish(self._TFMessage(transforms=[t]))

    def _on_cmd(self, msg) -> None:
        try:
            self._cmd = VelocityCommand(msg.linear.x, msg.linear.y, msg.angular.z)
            # never wait here: in lock-step the bus time waits for reads this executor delivers
            t = self._bus_time()
            self._cmd_time = math.nan if t is None else t       # nan: stamped by the worker on first use
        except LocomotionError as exc:
            self.get_logger().error(f'/cmd_vel rejected: {exc}', throttle_duration_sec=1.0)   # a flood: one a second

    def _bus_time(self) -> float | None:
        return self.bus.time_hint() if isinstance(self.bus, MasterClocked) else self.bus.now()

    def _current_cmd(self) -> VelocityCommand | None:
        timeout = self.get_parameter('cmd_vel_timeout_s').value
        if self._cmd_time is None:
            return self._cmd if self._cmd.vx or self._cmd.vy or self._cmd.wz else None
        if math.isnan(self._cmd_time):
            self._cmd_time = self.bus.now()
        if self.bus.now() - self._cmd_time > timeout:
            return None
        return self._cmd

    def _publish_read(self, r) -> None:
        # lock-stepped, the bus master waits for the goals: a read's age does not delay them
        age = self.bus.read_age_s if isinstance(self.bus, MasterClocked) and not self.params.lockstep else None
        warning = self.timing.on_read(r.leg, r.step, r.stamp_s, age)
        if warning is not None:
            self.get_logger().warning(warning)
            self._publish_diagnostics()
        m = self._LGD()
        m.header.stamp.sec, m.header.stamp.nanosec = stamp_parts(r.stamp_s)
        m.header.frame_id = joint_name(r.leg, 'femur')
        m.swing_start.sec, m.swing_start.nanosec = stamp_parts(r.stamp_s - r.t_swing_s)
        m.leg, m.detector, m.t_swing_s = r.leg, r.detector, r.t_swing_s
        m.theta_des_tick, m.theta_real_tick = r.theta_des_tick, r.theta_real_tick
        m.theta_est_tick, m.err_tick, m.err_est_tick = r.theta_est_tick, r.err_tick, r.err_est_tick
        m.threshold_tick, m.stopped, m.stop_reason = r.threshold_tick, r.stopped, r.stop_reason
        self.det_pub.publish(m)

    def _publish_swing_start(self, phase) -> None:
        # Algorithm 1 reads only the femurs of the swinging legs, in order (t_con = L * T_com)
        self.bus.set_schedule([joint_name(leg, 'femur') for leg in phase.legs])
        self.timing.start_phase(phase)
        m = self._SDS()
        m.header.stamp.sec, m.header.stamp.nanosec = stamp_parts(phase.t_start_s)
        for k, v in swing_start_fields(phase).items():
            setattr(m, k, v)
        self.swing_pub.publish(m)

    def _log_phase(self, rep) -> None:
        legs = ', '.join(f'leg {o.leg}: {"ground" if o.stop_reason == 1 else "NO GROUND"} after {o.stop_time_s:.3f} s'
                         for o in rep.outcomes)
        self.get_logger().info(f'phase {rep.phase}: {legs}')
        for w in rep.warnings:
            self.get_logger().warning(w)
        self._publish_diagnostics()

    def _publish_diagnostics(self) -> None:
        t = self._bus_time()
        self.diag_pub.publish(diagnostics.diagnostic_array([self.timing.status()], stamp_msg(0.0 if t is None else t)))

    def _run(self) -> None:
        try:
            if isinstance(self.bus, MasterClocked):
                self.bus.wait_for_master(self.get_logger().info)
            self.bus.set_schedule(ALL_JOINTS)
            self.bus.wait_until(self.bus.now() + 0.5)
            self.controller.startup(self.bus)
            while not self.bus.stopped.is_set():
                cmd = self._current_cmd()
                if cmd is None:
                    self.controller.finish(self.tap)      # a leveling left for the next swing: stand level
                    self.bus.wait_until(self.bus.now() + 0.05)
                    self.tap.update(self.bus.now())
                    continue
                est = self.tap.estimate
                if self.keeper is not None and est is not None:
                    p, gait = self.controller.params, self.controller.gait
                    cmd = self.keeper.command(self.bus.now(), cmd, est.position[:2], float(est.rpy[2]),
                                              p.cycle_s(gait), p.saturating_velocity(gait)[0])
                self.controller.step_phase(self.tap, cmd)
                self.tap.phase_done()
                self.bus.set_schedule(ALL_JOINTS)
        except (BusError, LocomotionError, DetectorError, OdometryError) as exc:
            if not self.bus.stopped.is_set():
                self.failed = True
                self.get_logger().error(f'locomotion stopped: {exc}')
        except InvalidHandle:
            # the node is being destroyed under this thread (its owner's shutdown): a normal stop
            return
        except RCLError:
            # SIGINT/SIGTERM shut the context down while this thread was publishing: a normal stop
            if self.context.ok():
                self.failed = True
                self.get_logger().error(f'locomotion stopped by a middleware error:\n{traceback.format_exc()}')
        except Exception:      # noqa: BLE001 - a bug: say where, and let main() end the process non-zero
            if not self.context.ok():
                # the context went away under this thread (SIGINT/SIGTERM): rclpy's bindings then raise
                # other errors than RCLError too (a TypeError from a handle already invalid): a normal stop
                return
            self.failed = True
            self.get_logger().error(f'locomotion stopped by an unexpected error:\n{traceback.format_exc()}')

    @property
    def running(self) -> bool:
        """The controller thread is alive (it only ends on a stop or a failure)."""
        return self._worker.is_alive()

    def destroy_node(self):
        self.bus.stopped.set()
        self._worker.join(timeout=2.0)
        return super().destroy_node()


def spin_while_walking(executor, node: LocomotionNode) -> None:
    """Spin until shutdown, or until the controller thread has ended (then raise SystemExit(1) if it
    failed: a supervisor or the user restarts the node; the bus master holds the last goals).

    Everything made while starting (imports, the robot model, compiled kernels, the MuJoCo model:
    about 180,000 objects) is moved out of the garbage collector's reach first (``gc.freeze``).
    Without that, each full collection traverses them all: 120-290 ms with the interpreter held,
    measured in the composed robot: twice during start-up and once in a 25 s walk (none with the freeze)
    - a stall in which a landing leg keeps pushing against the ground."""
    gc.freeze()
    while rclpy.ok(context=node.context) and node.running:
        executor.spin_once(timeout_sec=0.1)
    if node.failed:
        raise SystemExit(1)


def _spin(node: LocomotionNode) -> None:
    # One thread is enough: no callback of this node waits (the controller runs in its own
    # thread), and rclpy's MultiThreadedExecutor costs about as much CPU per message again as the
    # rest of the node (wait set rebuilt per message, a thread-pool hand-off per callback): over
    # DDS in lock-step that was 40 % of the node's CPU per simulated millisecond.
    ex = SingleThreadedExecutor()
    ex.add_node(node)
    try:
        spin_while_walking(ex, node)
    finally:                  # its pending tasks end with it, before the context goes (no Task.__del__ noise)
        ex.shutdown()


def main(args=None):
    run_node('locomotion_node', LocomotionNode, node_help('locomotion_node', __doc__, NODE.schemas), args,
             errors=(DescriptionError, GaitError, DetectorError, LocomotionError), spin=_spin, spec=NODE)


if __name__ == '__main__':
    main()
