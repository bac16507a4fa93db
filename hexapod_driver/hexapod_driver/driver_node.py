"""ROS 2 node: the AX-12A bus as topics (recording contract of hexapod_model.contract).

Thin: declared parameters, message conversion, one library call per callback. The bus itself is
:class:`hexapod_driver.bus.DynamixelBus`; its loop runs in a dedicated thread (one
``DynamixelBus.step()`` per iteration), while the executor serves commands, the read schedule,
the emergency stop and the timing publisher. One lock inside DynamixelBus owns the bus.

In:  /joint_commands (sensor_msgs/JointState), /read_schedule (hexapod_msgs/ReadSchedule),
     /set_read_schedule (hexapod_msgs/SetReadSchedule, the same with an answer),
     /emergency_stop (std_srvs/Trigger).
Out: /joint_states (one message per read, stamped at the start of the read transaction),
     /servo_diagnostics (hexapod_msgs/ServoDiagnostics), /bus_timing (hexapod_msgs/BusTiming).
"""
from __future__ import annotations

import os
import signal
import sys
import threading
import traceback

import rclpy
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rcl_interfaces.msg import ParameterDescriptor
from rclpy.qos import QoSProfile
from sensor_msgs.msg import JointState
from std_srvs.srv import Trigger

from hexapod_model import contract
from hexapod_model.bus import BusError
from hexapod_model.description import ALL_JOINTS, BusJoint, load_robot
from hexapod_msgs.msg import BusTiming, ReadSchedule, ServoDiagnostics, ServoStatus
from hexapod_msgs.srv import SetReadSchedule

from .bus import FAULT_POLICIES, LIMIT_POLICIES, CommandError, DriverConfig, DynamixelBus


EXIT_OK = 0                 # clean shutdown (Ctrl-C, SIGTERM)
EXIT_STARTUP = 1            # bad parameter or start-up failure (nothing enabled, or torque turned off)
EXIT_BUS_LOOP_CRASH = 3     # unexpected exception in the bus loop: torque turned off, ERROR on diagnostics

# Test hook, not a parameter: with this environment variable set to 1, SIGUSR1 makes the bus loop
# raise a RuntimeError at its next step, so the tests can prove the crash path through the real
# process at a moment they choose (after their subscriptions have matched, say).
TEST_HOOK_RAISE_ENV = 'HEXAPOD_DRIVER_TEST_RAISE_ON_SIGUSR1'


def parameter_table(robot) -> list[tuple[str, object, str]]:
    """(name, default, description) of every node parameter except the per-joint lists."""
    d = DriverConfig()
    bus = robot.bus
    return [
        ('device', '/dev/hexapod_dynamixel',
         'serial device of the Dynamixel adapter (udev symlink, or the bus emulator pty)'),
        ('baud_rate', bus.baud_rate, 'bus baud rate; must match every servo (register 4) or nothing answers'),
        ('latency_timer_ms', d.latency_timer_ms,
         "USB adapter latency timer [ms] (udev sets 1); sizes the reply timeout. Too small: replies are declared "
         "lost; too large: a lost reply blocks the bus longer. Widened automatically when start-up measures "
         "later replies"),
        ('timeout_margin_ms', d.timeout_margin_ms,
         'extra reply timeout [ms] for host scheduling jitter; too small: replies delayed by the host count as lost'),
        ('startup_timeout_margin_ms', d.startup_timeout_margin_ms,
         'the same during start-up verification/configuration [ms]'),
        ('startup_attempts', d.startup_attempts,
         'tries per transaction during start-up (a noisy bus) before start-up gives up and names what failed'),
        ('return_delay_time', d.return_delay_time,
         'servo return delay (register 5, x 2 us) written at start-up; the factory 250 adds 0.5 ms to every read'),
        ('compliance_margin', robot.servo.compliance_margin_ticks,
         'compliance margin [ticks] (registers 26/27); must match the model'),
        ('compliance_slope', robot.servo.compliance_slope_ticks,
         'compliance slope (registers 28/29); changes the P gain the model assumes'),
        ('torque_limit', d.torque_limit, 'torque limit (register 34, 1..1023) written at start-up and on recovery'),
        ('write_angle_limits', d.write_angle_limits,
         'write the joint limits as EEPROM angle limits (the servo then refuses goals outside them itself)'),
        ('read_retries', d.read_retries, 'extra attempts per failed read before it counts as failed'),
        ('missing_after_failures', d.missing_after_failures, 'consecutive failed reads before a servo is skipped'),
        ('reprobe_period_s', d.reprobe_period_s, 'how often a skipped (silent) servo is tried again [s]'),
        ('reconnect_period_s', d.reconnect_period_s, 'how often a lost serial port is reopened [s]'),
        ('command_timeout_s', d.command_timeout_s,
         'commands stamped older than this are rejected, and with no command for this long the driver holds '
         'position [s]; 0 disables'),
        ('limit_policy', d.limit_policy, f'goals outside the joint limits: one of {LIMIT_POLICIES}'),
        ('fault_policy', d.fault_policy,
         f'on overheating/overload, after the servo\'s own alarm shutdown has zeroed its torque limit (limp): one '
         f'of {FAULT_POLICIES} (limp: also torque enable 0, joint out until restart; recover: restore the torque '
         f'limit at the present position once the alarm clears)'),
        ('diagnostics_period_s', d.diagnostics_period_s, 'period of a diagnostics round over all servos [s]'),
        ('read_period_s', bus.t_com_s,
         "minimum spacing of position reads [s]; default: the description's t_com_s, the read period the "
         "swing-down model assumes; 0 = back to back (bus-limited)"),
        ('timing_period_s', 1.0, 'period of /bus_timing messages [s]'),
        ('watchdog_timeout_s', 2.0,
         'report an ERROR (log and /servo_diagnostics) when no bus transaction has completed for this long [s]; '
         '0 disables'),
    ]


class DriverNode(Node):
    def __init__(self):
        super().__init__('hexapod_driver')
        robot_path = self._param('robot_description', '', 'robot description YAML; empty = the packaged robot.yaml')
        robot = load_robot(robot_path or None)
        v = {name: self._param(name, default, desc) for name, default, desc in parameter_table(robot)}
        timing_period, self.watchdog_s = v.pop('timing_period_s'), v.pop('watchdog_timeout_s')
        cfg = DriverConfig(joints=self._joints(robot), **v)
        if not timing_period > 0:
            raise ValueError(f'driver parameter timing_period_s: must be > 0, got {timing_period}')
        if not self.watchdog_s >= 0:
            raise ValueError(f'driver parameter watchdog_timeout_s: must be >= 0, got {self.watchdog_s}')
        hook = os.environ.get(TEST_HOOK_RAISE_ENV, '')
        if hook not in ('', '0', '1'):
            raise ValueError(f'{TEST_HOOK_RAISE_ENV} (test hook) must be 0 or 1, got {hook!r}')
        self._forced_raise = threading.Event()
        if hook == '1':
            signal.signal(signal.SIGUSR1, lambda *_: self._forced_raise.set())
        self.exit_code: int | None = None
        self.core = DynamixelBus(robot, cfg, clock=lambda: self.get_clock().now().nanoseconds * 1e-9)
        try:
            self.core.start()
        except BaseException:
            self.core.close()            # torque off whatever was already enabled
            raise
        for level, text in self.core.take_events():
            self._log(level, text)
        self.get_logger().info(f'{cfg.device}: {len(ALL_JOINTS)} AX-12A servos verified and configured; torque on')

        self.pub_states = self.create_publisher(JointState, contract.JOINT_STATES, QoSProfile(depth=200))
        self.pub_diag = self.create_publisher(ServoDiagnostics, contract.SERVO_DIAGNOSTICS, 10)
        self.pub_timing = self.create_publisher(BusTiming, contract.BUS_TIMING, 10)
        self.create_subscription(JointState, contract.JOINT_COMMANDS, self.on_command, 10)
        self.create_subscription(ReadSchedule, contract.READ_SCHEDULE, self.on_schedule, 10)
        self.create_service(SetReadSchedule, contract.SET_READ_SCHEDULE, self.on_set_schedule)
        self.create_service(Trigger, contract.EMERGENCY_STOP, self.on_emergency_stop)
        self.create_timer(timing_period, self.on_timing)
        self._watchdog_fired = False
        if self.watchdog_s > 0:
            self.create_timer(self.watchdog_s / 4.0, self.on_watchdog)
        self._running = threading.Event()
        self._running.set()
        self._thread = threading.Thread(target=self._bus_loop, name='bus-loop', daemon=True)
        self._thread.start()

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

    # ------------------------------------------------------------------ parameters
    def _param(self, name, default, description):
        self.declare_parameter(name, default, ParameterDescriptor(description=description, read_only=True))
        return self.get_parameter(name).value

    def _joints(self, robot) -> tuple[BusJoint, ...]:
        by = {j.joint: j for j in robot.bus.joints}
        order = 'in the order ' + ', '.join(ALL_JOINTS)
        ids = self._param('servo_ids', [by[j].servo_id for j in ALL_JOINTS], f'Dynamixel ID of each joint {order}')
        dirs = self._param('directions', [by[j].direction for j in ALL_JOINTS],
                           f'mounting direction (+1/-1) of each joint {order}; a wrong sign mirrors the joint')
        offs = self._param('offsets_ticks', [by[j].offset_ticks for j in ALL_JOINTS],
                           f'mounting offset [ticks] of each joint {order}')
        for name, v in (('servo_ids', ids), ('directions', dirs), ('offsets_ticks', offs)):
            if len(v) != len(ALL_JOINTS):
                raise ValueError(f'driver parameter {name}: needs {len(ALL_JOINTS)} entries ({order}), got {len(v)}')
        return tuple(BusJoint(j, int(i), int(d), int(o)) for j, i, d, o in zip(ALL_JOINTS, ids, dirs, offs))

    # ------------------------------------------------------------------ callbacks
    def on_command(self, msg: JointState) -> None:
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
        try:
            now = self.core.set_schedule(names)
        except CommandError as exc:
            self.get_logger().warn(f'read schedule rejected: {exc}')
            return False, str(exc)
        return True, 'reading ' + ', '.join(now)

    def on_emergency_stop(self, request, response):
        response.success, response.message = self.core.emergency_stop()
        self._log('warn' if response.success else 'error', response.message)
        return response

    def on_watchdog(self) -> None:
        if self.exit_code is not None:
            return
        idle = self.core.clock() - self.core.last_ok_t
        alive = self._thread.is_alive()
        if idle > self.watchdog_s or not alive:
            why = 'the bus loop thread has ended' if not alive else (
                'port lost' if not self.core.port_ok else self.core.last_failure or 'no answer')
            text = (f'watchdog: no bus transaction completed for {idle:.1f} s (watchdog_timeout_s='
                    f'{self.watchdog_s:g}): {why}')
            if not self._watchdog_fired:
                self._watchdog_fired = True
                self.get_logger().error(text)
                self.pub_diag.publish(self._error_diagnostics(f'ERROR {text}'))
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

    def _bus_loop(self) -> None:
        steps = 0
        try:
            while self._running.is_set() and self.context.ok():
                if self._forced_raise.is_set():
                    raise RuntimeError(f'{TEST_HOOK_RAISE_ENV}=1 and SIGUSR1 after {steps} steps: exception '
                                       f'forced inside the bus loop (test hook)')
                res = self.core.step()
                steps += 1
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
                self.pub_diag.publish(self._error_diagnostics(
                    f'ERROR bus loop crashed, turning torque off: {tb.strip().splitlines()[-1]}'))
            except Exception:            # noqa: BLE001 - the context may be going down meanwhile
                pass
        ok, torque = self.core.shutdown()
        text = f'bus loop crashed; {torque}; the driver exits with code {EXIT_BUS_LOOP_CRASH}'
        if self.context.ok():
            self.get_logger().error(f'{text}\n{tb}')
            try:
                self.pub_diag.publish(self._error_diagnostics(f'ERROR {text}: {tb.strip().splitlines()[-1]}'))
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
        for level, text in res.events:
            self._log(level, text)

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
        """Stop the loop thread, torque off, close the port; log only what the driver knows."""
        self._running.clear()
        if self._thread.is_alive():
            self._thread.join(timeout=2.0)
        ok, text = self.core.shutdown()
        if self.exit_code == EXIT_BUS_LOOP_CRASH:
            return                       # reported with the crash
        text = f'{text}; port closed'
        if self.context.ok():
            self._log('info' if ok else 'error', text)
        else:                            # after Ctrl-C the logger can no longer reach /rosout
            print(f'[hexapod_driver] {text}', file=sys.stderr, flush=True)


HELP = """usage: driver_node [-h] [--ros-args -p NAME:=VALUE ...]

The AX-12A bus as ROS 2 topics (see docs/real-robot.md). Parameters (-p NAME:=VALUE):
"""


def print_help() -> None:
    robot = load_robot()
    lines = [HELP, '  robot_description (default \'\'): robot description YAML; empty = the packaged robot.yaml']
    for name, default, desc in parameter_table(robot):
        lines.append(f'  {name} (default {default!r}): {desc}')
    lines.append('  servo_ids, directions, offsets_ticks: 18 entries each, in the order ' + ', '.join(ALL_JOINTS)
                 + ' (default: the robot description)')
    lines.append(f'\nExit codes: {EXIT_OK} clean shutdown; {EXIT_STARTUP} bad parameter or start-up failure; '
                 f'{EXIT_BUS_LOOP_CRASH} the bus loop crashed (torque turned off, ERROR on /servo_diagnostics).')
    print('\n'.join(lines))


def main(args=None) -> int:
    argv = sys.argv[1:] if args is None else list(args)
    own = argv[:argv.index('--ros-args')] if '--ros-args' in argv else argv
    if '-h' in own or '--help' in own:
        print_help()                     # never opens the serial device
        return EXIT_OK
    rclpy.init(args=args)
    node = None
    rc = EXIT_OK
    executor = SingleThreadedExecutor()
    try:
        node = DriverNode()
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
