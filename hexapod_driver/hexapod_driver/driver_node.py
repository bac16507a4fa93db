"""ROS 2 node: the AX-12A bus as topics (recording contract of hexapod_model.contract), as a managed
(lifecycle) node, the convention of ros2_control hardware.

Lifecycle: *configure* opens the port, verifies the servos and configures them (torque off);
*activate* sets each goal to the present position, turns torque on and starts the bus loop;
*deactivate* stops the loop and turns torque off; *cleanup* closes the port; *shutdown* (from any
state) turns torque off and closes the port. With ``autostart`` (the default) the node goes to
active at start-up, so ``ros2 run hexapod_driver driver_node`` drives the servos at once; with
``autostart:=false`` it waits for ``/<node>/change_state``.

Thin: declared parameters, message conversion, one library call per callback. The bus itself is
:class:`hexapod_driver.bus.DynamixelBus` (built by ``bus_factory``); its loop runs in a dedicated
thread while active (one ``DynamixelBus.step()`` per iteration), while the executor serves
commands, the read schedule, the emergency stop, the lifecycle services and the timing publisher.

In:  /joint_commands (sensor_msgs/JointState), /read_schedule (hexapod_msgs/ReadSchedule),
     /set_read_schedule (hexapod_msgs/SetReadSchedule, the same with an answer),
     /emergency_stop (std_srvs/Trigger).
Out: /joint_states (one message per read, stamped at the start of the read transaction),
     /servo_diagnostics (hexapod_msgs/ServoDiagnostics), /bus_timing (hexapod_msgs/BusTiming),
     /diagnostics (diagnostic_msgs/DiagnosticArray: every servo and the bus, each timing period
     and at once on an error; the mapping is hexapod_model.diagnostics). All but /diagnostics are
     lifecycle publishers: silent unless the node is active; while inactive, /joint_commands are
     ignored (a warning says so) and only the read schedule and the emergency stop are taken.
Events of the bus are logged as ``[kind] text`` (:class:`hexapod_driver.bus.Event`).
"""
from __future__ import annotations

import sys
import threading
import time
import traceback
from typing import Callable

import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.lifecycle import LifecycleNode, LifecycleState, TransitionCallbackReturn
from rclpy.qos import QoSProfile
from sensor_msgs.msg import JointState
from std_srvs.srv import Trigger

from hexapod_driver.bus import CommandError, DynamixelBus, Event
from hexapod_driver.config import NODE, DriverConfig, DriverNodeParams, robot_defaults
from hexapod_driver.local_bus import LocalDriverBus
from hexapod_model import contract, diagnostics
from hexapod_model.bus import BusError
from hexapod_model.cli_common import prog_name
from hexapod_model.description import ALL_JOINTS, DescriptionError
from hexapod_model.node_params import NodeParams, init_node_process, node_command_line, refuse_unknown_parameters
from hexapod_model.param_schema import ParameterError, RobotSource, help_lines
from hexapod_msgs.msg import BusTiming, ReadSchedule, ServoDiagnostics, ServoStatus
from hexapod_msgs.srv import SetReadSchedule

EXIT_OK = 0                 # clean shutdown (Ctrl-C, SIGTERM)
EXIT_STARTUP = 1            # bad parameter or start-up failure (nothing enabled, or torque turned off)
EXIT_BUS_LOOP_CRASH = 3     # unexpected exception in the bus loop: torque turned off, ERROR on diagnostics

SUCCESS, FAILURE = TransitionCallbackReturn.SUCCESS, TransitionCallbackReturn.FAILURE


class DriverNode(LifecycleNode):
    """The driver node; ``bus_factory(robot, config, clock=...)`` builds its bus (a test's, to
    inject faults through the objects the node is built from)."""

    def __init__(self, bus_factory: Callable[..., DynamixelBus] = DynamixelBus, **node_kwargs):
        super().__init__(NODE.node_name, **node_kwargs)
        params = NodeParams(self)
        robot = params.declare(RobotSource).load()        # servo mounting: the description's bus.joints
        self.cfg = params.declare(DriverConfig, defaults=robot_defaults(robot))
        own = params.declare(DriverNodeParams)
        self.watchdog_s = own.watchdog_timeout_s
        self.exit_code: int | None = None
        # The bus runs on ROS time: the system clock, read directly (rclpy's Clock.now() costs some
        # 15 us, several times per transaction), or /clock with use_sim_time.
        ros_time = lambda: self.get_clock().now().nanoseconds * 1e-9     # noqa: E731
        self.core = bus_factory(robot, self.cfg, clock=ros_time if self.get_parameter('use_sim_time').value
                                else time.time)
        self._active = False
        self._configured = False                  # the port is open (configure succeeded, no cleanup since)
        self._failure: BusError | None = None     # why the last transition failed
        self._local: LocalDriverBus | None = None
        self._running = threading.Event()
        self._thread: threading.Thread | None = None
        self._watchdog_fired = False
        self._quiet_failures = False              # at start-up a failure is main's one line, not a log line too
        # The data topics are lifecycle publishers: silent unless active. /diagnostics is not: it
        # reports the servos and the bus (torque off, port closed) in every state.
        self.pub_states = self.create_lifecycle_publisher(JointState, contract.JOINT_STATES, QoSProfile(depth=200))
        self.pub_diag = self.create_lifecycle_publisher(ServoDiagnostics, contract.SERVO_DIAGNOSTICS, 10)
        self.pub_timing = self.create_lifecycle_publisher(BusTiming, contract.BUS_TIMING, 10)
        self.pub_diagnostics = self.create_publisher(DiagnosticArray, contract.DIAGNOSTICS, 10)
        self._timing_t0 = self.get_clock().now()
        if own.autostart:                         # before the services: a client that finds them finds torque on
            self._autostart()
        self._subs = [self.create_subscription(JointState, contract.JOINT_COMMANDS, self.on_command, 10),
                      self.create_subscription(ReadSchedule, contract.READ_SCHEDULE, self.on_schedule, 10)]
        self.create_service(SetReadSchedule, contract.SET_READ_SCHEDULE, self.on_set_schedule)
        self.create_service(Trigger, contract.EMERGENCY_STOP, self.on_emergency_stop)
        self.create_timer(own.timing_period_s, self.on_timing)
        if self.watchdog_s > 0:
            self.create_timer(self.watchdog_s / 4.0, self.on_watchdog)

    def _autostart(self) -> None:
        """configure, then activate; a failure raises (the caller exits with one line)."""
        self._quiet_failures = True
        try:
            for trigger in (self.trigger_configure, self.trigger_activate):
                self._failure = None
                if trigger() != SUCCESS:
                    self.shutdown_bus()
                    raise self._failure or BusError('lifecycle transition failed at start-up')
        finally:
            self._quiet_failures = False

    # ------------------------------------------------------------------ lifecycle
    def on_configure(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Open the port, verify and configure the servos; torque stays off."""
        try:
            self.core.open(enable_torque=False)
        except BusError as exc:
            self.core.close()            # torque off whatever was already enabled
            self._log_events(self.core.take_events())
            return self._failed(exc, 'configure')
        self._log_events(self.core.take_events())
        self._configured = True
        self.get_logger().info(f'{self.cfg.device}: {len(ALL_JOINTS)} AX-12A servos verified and configured; '
                               f'torque off until activated')
        return SUCCESS

    def on_activate(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Goals to the present positions, torque on, the bus loop started."""
        try:
            self.core.enable_torque()
        except BusError as exc:
            ok, text = self.core.torque_off_report()
            return self._failed(BusError(f'{exc}; {text}'), 'activate')
        self._log_events(self.core.take_events())
        super().on_activate(state)       # the lifecycle publishers, before the loop's first reading
        self._active = True
        self._watchdog_fired = False
        self._running.set()
        self._thread = threading.Thread(target=self._bus_loop, name='bus-loop', daemon=True)
        self._thread.start()
        self.get_logger().info(f'{self.cfg.device}: torque on; the bus loop runs')
        return SUCCESS

    def on_deactivate(self, state: LifecycleState) -> TransitionCallbackReturn:
        """The data topics silent, the bus loop stopped, torque off (read back)."""
        super().on_deactivate(state)
        self._stop_loop()
        ok, text = self.core.torque_off_report()
        self._log('info' if ok else 'error', f'deactivated: {text}')
        return SUCCESS

    def on_cleanup(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Torque off (again) and the port closed."""
        ok, text = self.core.shutdown()
        self._configured = False
        self._log('info' if ok else 'error', f'cleaned up: {text}; port closed')
        return SUCCESS

    def on_shutdown(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Torque off and the port closed, from any state; then the process ends (exit code 0)."""
        self.shutdown_bus()
        if self.exit_code is None:
            self.exit_code = EXIT_OK
        return SUCCESS

    def on_error(self, state: LifecycleState) -> TransitionCallbackReturn:
        self.shutdown_bus()
        return SUCCESS

    def _failed(self, exc: BusError, transition: str) -> TransitionCallbackReturn:
        self._failure = exc
        if not self._quiet_failures:
            self.get_logger().error(f'{transition} failed: {exc}')
        return FAILURE

    def _stop_loop(self) -> None:
        self._active = False
        if self._local is not None:
            self._local.stopped.set()    # the composed controller stops with the loop
        self._running.clear()
        if self._thread is not None and self._thread.is_alive() and self._thread is not threading.current_thread():
            self._thread.join(timeout=2.0)

    def local_bus(self) -> LocalDriverBus:
        """Hand the bus to a controller in this process (the ``robot`` executable): the bus-loop
        thread ends and the controller's thread runs the bus (reads, writes, and between them the
        loop's own reads and diagnostics). ``/joint_commands`` and ``/read_schedule`` are no longer
        taken from topics (two masters would fight over the bus); the controller's writes are
        published on ``/joint_commands`` instead, so the graph and its recordings look the same."""
        if self._local is not None:
            return self._local
        if not self._active:
            raise BusError('the driver is not active (autostart:=false?): a composed controller needs it active')
        self._running.clear()
        self._thread.join()
        for sub in self._subs:
            self.destroy_subscription(sub)
        self._subs = []
        pub_cmd = self.create_lifecycle_publisher(JointState, contract.JOINT_COMMANDS, QoSProfile(depth=200))
        pub_cmd.on_activate(None)        # created while active: enabled now, disabled with the others

        def on_read(joint, theta, stamp):
            js = JointState()
            js.header.stamp = contract.stamp_msg(stamp)
            js.name, js.position = [joint], [theta]
            self.pub_states.publish(js)

        def on_write(stamp, goals):
            js = JointState()
            js.header.stamp = contract.stamp_msg(stamp)
            js.name, js.position = list(goals), [float(v) for v in goals.values()]
            pub_cmd.publish(js)

        self._local = LocalDriverBus(self.core, on_read, on_write, self._publish)
        self._log_events(self.core.take_events())
        return self._local

    def _log(self, level: str, text: str) -> None:
        """Log at a level chosen at run time: one call site per severity (rclpy refuses a call
        site whose severity changes between calls)."""
        logger = self.get_logger()
        if level == 'error':
            logger.error(text)
        elif level == 'warn':
            logger.warning(text)
        else:
            logger.info(text)

    def _log_events(self, events: list[Event]) -> None:
        for ev in events:
            self._log(ev.level, ev.log_line())

    # ------------------------------------------------------------------ callbacks
    def on_command(self, msg: JointState) -> None:
        if not self._active:
            self.get_logger().warn('command ignored: the driver is not active (lifecycle)', throttle_duration_sec=1.0)
            return
        stamp = contract.stamp_seconds(msg.header.stamp)
        try:
            warnings = self.core.set_command(list(msg.name), list(msg.position), stamp or None)
        except CommandError as exc:
            self.get_logger().warn(f'command rejected: {exc}', throttle_duration_sec=1.0)
            return
        for w in warnings:
            self.get_logger().warn(w, throttle_duration_sec=1.0)

    def on_schedule(self, msg: ReadSchedule) -> None:
        self._set_schedule(msg.joint_names)

    def on_set_schedule(self, request, response):
        response.success, response.message = self._set_schedule(request.joint_names)
        return response

    def _set_schedule(self, names) -> tuple[bool, str]:
        if self._local is not None:
            return False, 'the read schedule belongs to the controller composed with this driver'
        try:
            now = self.core.set_schedule(names)
        except CommandError as exc:
            self.get_logger().warn(f'read schedule rejected: {exc}')
            return False, str(exc)
        return True, 'reading ' + ', '.join(now)

    def on_emergency_stop(self, request, response):
        if not self._configured:
            response.success, response.message = False, 'emergency stop: the driver is unconfigured (port closed)'
            self.get_logger().error(response.message)
            return response
        response.success, response.message = self.core.emergency_stop()
        self._log('warn' if response.success else 'error', response.message)
        return response

    def on_watchdog(self) -> None:
        if self.exit_code is not None or not self._active:
            return
        idle = self.core.clock() - self.core.last_ok_t
        alive = self._thread.is_alive() or self._local is not None   # composed: the controller runs the bus
        if idle > self.watchdog_s or not alive:
            why = 'the bus loop thread has ended' if not alive else (
                'port lost' if not self.core.port_ok else self.core.last_failure or 'no answer')
            text = (f'watchdog: no bus transaction completed for {idle:.1f} s (watchdog_timeout_s='
                    f'{self.watchdog_s:g}): {why}')
            if not self._watchdog_fired:
                self._watchdog_fired = True
                self.get_logger().error(text)
                self._publish_error(f'ERROR {text}')
        elif self._watchdog_fired:
            self._watchdog_fired = False
            self.get_logger().info('watchdog: bus transactions complete again')

    def on_timing(self) -> None:
        snap = self.core.timing.snapshot(reset=True)
        msg = BusTiming()
        msg.header.stamp = self.get_clock().now().to_msg()
        msg.reads, msg.failed_reads = snap.reads, snap.failed_reads
        msg.t_com_mean_s, msg.t_com_p99_s, msg.t_com_max_s = snap.t_com_mean_s, snap.t_com_p99_s, snap.t_com_max_s
        msg.write_mean_s = snap.write_mean_s
        self.pub_timing.publish(msg)
        now = self.get_clock().now()
        window_s, self._timing_t0 = (now - self._timing_t0).nanoseconds * 1e-9, now
        bus = diagnostics.bus_status(self.core.robot, self.get_name(), window_s=window_s, reads=snap.reads,
                                     failed_reads=snap.failed_reads, t_com_mean_s=snap.t_com_mean_s,
                                     t_com_p99_s=snap.t_com_p99_s, t_com_max_s=snap.t_com_max_s,
                                     write_mean_s=snap.write_mean_s)
        self.pub_diagnostics.publish(diagnostics.diagnostic_array([bus, *self._servo_statuses()], now.to_msg()))

    def _servo_statuses(self, responding: bool | None = None, note: str = '') -> list:
        out = []
        for j in ALL_JOINTS:
            st = self.core.states[j]
            out.append(diagnostics.servo_status(
                self.core.robot, self.get_name(), j, st.servo_id, temperature_c=st.temperature_c,
                voltage_v=st.voltage_v, load_fraction=st.load_fraction, error_bits=st.error_bits,
                responding=st.responding if responding is None else responding,
                torque_enabled=st.torque_enabled, torque_limit=st.torque_limit, note=note or st.message))
        return out

    def _publish_error(self, text: str) -> None:
        """An ERROR on /servo_diagnostics and /diagnostics (watchdog, bus-loop crash)."""
        self.pub_diag.publish(self._error_diagnostics(text))
        nan = float('nan')
        bus = diagnostics.bus_status(self.core.robot, self.get_name(), window_s=0.0, reads=0, failed_reads=0,
                                     t_com_mean_s=nan, t_com_p99_s=nan, t_com_max_s=nan, write_mean_s=nan, note=text)
        stamp = self.get_clock().now().to_msg()
        self.pub_diagnostics.publish(diagnostics.diagnostic_array([bus, *self._servo_statuses(False, text)], stamp))

    def _bus_loop(self) -> None:
        try:
            while self._running.is_set() and self.context.ok():
                res = self.core.step()
                try:
                    self._publish(res)
                except Exception:        # noqa: BLE001 - Ctrl-C shuts the context down under this thread
                    if self.context.ok():
                        raise
                    return
        except Exception:                # noqa: BLE001 - never die silently: torque off, report, exit non-zero
            self._bus_loop_crashed(traceback.format_exc())

    def _bus_loop_crashed(self, tb: str) -> None:
        if self.context.ok():            # first word out before the torque-off round (which takes a while)
            try:
                self._publish_error(f'ERROR bus loop crashed, turning torque off: {tb.strip().splitlines()[-1]}')
            except Exception:            # noqa: BLE001 - the context may be going down meanwhile
                pass
        self._active = False
        ok, torque = self.core.shutdown()
        text = f'bus loop crashed; {torque}; the driver exits with code {EXIT_BUS_LOOP_CRASH}'
        if self.context.ok():
            self.get_logger().error(f'{text}\n{tb}')
            try:
                self._publish_error(f'ERROR {text}: {tb.strip().splitlines()[-1]}')
            except Exception:            # noqa: BLE001 - the context may be going down meanwhile
                pass
        else:
            print(f'[hexapod_driver] {text}\n{tb}', file=sys.stderr, flush=True)
        self.exit_code = EXIT_BUS_LOOP_CRASH

    def _error_diagnostics(self, text: str) -> ServoDiagnostics:
        msg = ServoDiagnostics()
        msg.header.stamp = self.get_clock().now().to_msg()
        for j in ALL_JOINTS:
            st = self.core.states[j]
            s = ServoStatus()
            s.joint_name, s.id = st.joint, st.servo_id
            s.temperature_c, s.voltage_v, s.load_fraction = st.temperature_c, st.voltage_v, st.load_fraction
            s.error_bits, s.responding = st.error_bits, False
            s.torque_enabled = bool(st.torque_enabled and st.torque_limit)
            s.message = text
            msg.servos.append(s)
        return msg

    def _publish(self, res) -> None:
        for s in res.samples:
            js = JointState()
            js.header.stamp = contract.stamp_msg(s.stamp)
            js.name = [s.joint]
            js.position = [s.theta_rad]
            self.pub_states.publish(js)
        if res.diagnostics is not None:
            self.pub_diag.publish(self._diagnostics(res.diagnostics))
        self._log_events(res.events)
        errors = [ev.text() for ev in res.events if ev.level == 'error']
        if errors:
            self._publish_now('; '.join(errors))

    def _publish_now(self, text: str) -> None:
        """/diagnostics at once on an error event (port lost, a servo stopped answering, an alarm):
        one lasting less than ``timing_period_s`` would otherwise fall between two periodic arrays.
        The bus status carries the text; the window counts so far are not reset."""
        snap = self.core.timing.snapshot(reset=False)
        now = self.get_clock().now()
        bus = diagnostics.bus_status(self.core.robot, self.get_name(),
                                     window_s=(now - self._timing_t0).nanoseconds * 1e-9, reads=snap.reads,
                                     failed_reads=snap.failed_reads, t_com_mean_s=snap.t_com_mean_s,
                                     t_com_p99_s=snap.t_com_p99_s, t_com_max_s=snap.t_com_max_s,
                                     write_mean_s=snap.write_mean_s, note=text)
        self.pub_diagnostics.publish(diagnostics.diagnostic_array([bus, *self._servo_statuses()], now.to_msg()))

    def _diagnostics(self, states) -> ServoDiagnostics:
        msg = ServoDiagnostics()
        msg.header.stamp = self.get_clock().now().to_msg()
        for st in states:
            s = ServoStatus()
            s.joint_name, s.id = st.joint, st.servo_id
            s.temperature_c, s.voltage_v, s.load_fraction = st.temperature_c, st.voltage_v, st.load_fraction
            # torque_enabled: the servo produces torque (enable = 1 and a non-zero torque limit); an
            # alarm shutdown zeroes the limit, the message says so
            s.error_bits, s.responding = st.error_bits, st.responding
            s.torque_enabled = bool(st.torque_enabled and st.torque_limit)
            s.message = st.message
            msg.servos.append(s)
        return msg

    def shutdown_bus(self) -> None:
        """Stop the loop thread, torque off, close the port (safe to call twice); log only what the
        driver knows. Unconfigured, the port is closed already and torque was never enabled."""
        self._stop_loop()
        if not self._configured:
            return
        self._configured = False
        ok, text = self.core.shutdown()
        if self.exit_code == EXIT_BUS_LOOP_CRASH:
            return                       # reported with the crash
        text = f'{text}; port closed'
        if self.context.ok():
            self._log('info' if ok else 'error', text)
        else:                            # after Ctrl-C the logger can no longer reach /rosout
            print(f'[hexapod_driver] {text}', file=sys.stderr, flush=True)


HELP = """usage: {prog} [-h] [--ros-args -p NAME:=VALUE ...]

The AX-12A bus as ROS 2 topics (see docs/real-robot.md). Servo IDs, mounting directions and offsets
come from the robot description (robot_description + robot_overlays). Parameters (-p NAME:=VALUE):
"""


def help_text() -> str:
    lines = [HELP.format(prog=prog_name('driver_node')), *help_lines(NODE.schemas, NODE.defaults())]
    lines.append(f'\nExit codes: {EXIT_OK} clean shutdown; {EXIT_STARTUP} bad parameter or start-up failure; '
                 f'{EXIT_BUS_LOOP_CRASH} the bus loop crashed (torque turned off, ERROR on /servo_diagnostics).')
    return '\n'.join(lines)


def main(args=None, bus_factory: Callable[..., DynamixelBus] = DynamixelBus) -> int:
    """The executable; ``bus_factory`` builds the node's bus (see :class:`DriverNode`)."""
    rc = node_command_line(args, 'driver_node', help_text)      # --help never opens the serial device
    if rc is not None:
        return rc
    init_node_process(args)
    node = None
    rc = EXIT_OK
    executor = SingleThreadedExecutor()
    try:
        refuse_unknown_parameters(NODE.node_name, NODE.names())      # before the device is opened
        node = DriverNode(bus_factory)
        executor.add_node(node)
        while node.exit_code is None and node.context.ok():
            try:
                executor.spin_once(timeout_sec=0.2)
            except Exception:            # noqa: BLE001 - SIGTERM/Ctrl-C invalidates the context mid-wait
                if node.context.ok():
                    raise
        rc = EXIT_OK if node.exit_code is None else node.exit_code
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except (ParameterError, DescriptionError) as exc:
        print(f'[hexapod_driver] {exc}', file=sys.stderr, flush=True)     # nothing was opened
        rc = EXIT_STARTUP
    except (BusError, ValueError) as exc:
        print(f'[hexapod_driver] start-up failed: {exc}', file=sys.stderr, flush=True)
        rc = EXIT_STARTUP
    finally:
        if node is not None:
            node.shutdown_bus()
            executor.remove_node(node)
            node.destroy_node()
        executor.shutdown()
        rclpy.try_shutdown()
    return rc


if __name__ == '__main__':
    sys.exit(main())
