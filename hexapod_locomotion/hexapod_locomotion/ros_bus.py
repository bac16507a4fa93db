"""The servo bus seen through ROS topics: implements :class:`hexapod_model.bus.ServoBus` on top of
the driver's (or the sim node's) interface, so :class:`GaitController` runs unchanged behind the
locomotion node.

* ``sync_write`` publishes one ``/joint_commands`` message (stamped now).
* ``read_position(joint)`` asks the bus master for that joint via ``/read_schedule`` (when the
  schedule changes) and returns the next ``/joint_states`` message for the joint sampled after the
  request, with its sample stamp. Reads arrive in schedule order from the driver.
* ``wait_until`` waits on the node clock (ROS time, or /clock with use_sim_time).
* ``lockstep``: the bus master (sim_node with ``lockstep:=true``) advances one read-schedule cycle
  per ``/joint_commands`` message; waiting and reading then publish empty commands to advance it,
  so a run does not depend on machine load.
"""
from __future__ import annotations

import collections
import threading
import time

from hexapod_model.bus import BusError
from hexapod_model.contract import JOINT_COMMANDS, JOINT_STATES, READ_SCHEDULE


class RosBus:
    def __init__(self, node, t_com_s: float, read_timeout_s: float = 0.5, lockstep: bool = False):
        from hexapod_msgs.msg import ReadSchedule
        from sensor_msgs.msg import JointState
        self._JointState = JointState
        self._ReadSchedule = ReadSchedule
        self.node = node
        self.t_com_s = t_com_s
        self.read_timeout_s = read_timeout_s
        self.lockstep = lockstep
        self._last_write = -1.0
        self._consumed: dict[str, float] = {}
        self._newest = None         # newest read stamp received (lock-step time base)
        self._cv = threading.Condition()
        self._latest: dict[str, collections.deque] = collections.defaultdict(lambda: collections.deque(maxlen=64))
        self._schedule: tuple[str, ...] = ()
        # deep queues: with a slow bus master (a loaded machine) a reliable writer's shallow history
        # would drop goals before they are acknowledged
        self._cmd_pub = node.create_publisher(JointState, JOINT_COMMANDS, 1000)
        self._sched_pub = node.create_publisher(ReadSchedule, READ_SCHEDULE, 10)
        node.create_subscription(JointState, JOINT_STATES, self._on_state, 1000)
        self.stopped = threading.Event()

    # -- subscription callback (executor thread)
    def _on_state(self, msg) -> None:
        t = msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9
        with self._cv:
            for i, name in enumerate(msg.name):
                if i < len(msg.position):
                    self._latest[name].append((t, float(msg.position[i])))
            self._newest = t if self._newest is None else max(self._newest, t)
            self._cv.notify_all()

    def now(self) -> float:
        if self.lockstep and self._newest is not None:
            # the bus master advances only on our commands: its time is what its reads have shown
            # (/clock can run ahead of the reads still in flight)
            return self._newest + self.t_com_s
        return self.node.get_clock().now().nanoseconds * 1e-9

    def sync_write(self, goals_rad) -> float:
        msg = self._JointState()
        msg.header.stamp = self.node.get_clock().now().to_msg()
        msg.name = list(goals_rad)
        msg.position = [float(v) for v in goals_rad.values()]
        self._cmd_pub.publish(msg)
        self._last_write = msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9
        return self._last_write

    def _advance(self) -> None:
        """Lock-step: an empty command makes the bus master run one more read cycle. Called with
        ``_cv`` held; waits until that cycle's reads start arriving, so requests never pile up in
        the command queue (where they would push out real goals on a slow machine)."""
        seen = self._newest
        msg = self._JointState()
        msg.header.stamp = self.node.get_clock().now().to_msg()
        self._cmd_pub.publish(msg)
        self._cv.wait_for(lambda: self._newest != seen or self.stopped.is_set(), timeout=self.read_timeout_s)

    def set_schedule(self, joints) -> None:
        joints = tuple(joints)
        if joints != self._schedule:
            m = self._ReadSchedule()
            m.header.stamp = self.node.get_clock().now().to_msg()
            m.joint_names = list(joints)
            self._sched_pub.publish(m)
            self._schedule = joints

    def _fresh(self, joint: str):
        """Newest read of ``joint`` sampled after our last write and after the last one consumed."""
        q = self._latest[joint]
        floor = max(self._last_write - 1e-9, self._consumed.get(joint, -1.0) + 1e-9)
        while q and q[0][0] < floor:
            q.popleft()
        return q[-1] if q else None

    def read_position(self, joint: str) -> tuple[float, float]:
        if self._schedule and joint not in self._schedule:
            self.set_schedule(self._schedule + (joint,))
        deadline = time.monotonic() + self.read_timeout_s
        with self._cv:
            while True:
                if self.stopped.is_set():
                    raise BusError('locomotion stopped')
                got = self._fresh(joint)
                if got is not None:
                    self._latest[joint].clear()
                    self._consumed[joint] = got[0]
                    return got[1], got[0]
                if time.monotonic() > deadline:
                    raise BusError(f'no /joint_states reading of {joint} within {self.read_timeout_s} s '
                                   f'(is the driver or sim running and reading it?)')
                if self.lockstep:
                    self._advance()
                else:
                    self._cv.wait(timeout=0.005)

    def wait_until(self, t: float) -> None:
        deadline = time.monotonic() + max(10.0, 100 * self.read_timeout_s)
        while not self.stopped.is_set() and self.now() < t:
            if time.monotonic() > deadline:
                raise BusError(f'bus time did not reach {t:.3f} s (clock at {self.now():.3f} s): is /clock published?')
            if self.lockstep:
                with self._cv:
                    self._advance()
            else:
                self.stopped.wait(min(0.0005, max(t - self.now(), 0.0)))
