"""The servo bus seen through ROS topics: implements :class:`hexapod_model.bus.ServoBus` on top of
the driver's (or the sim node's) interface, so :class:`GaitController` runs unchanged behind the
locomotion node.

* ``sync_write`` publishes one ``/joint_commands`` message (stamped now).
* ``read_position(joint)`` asks the bus master for that joint via ``/read_schedule`` (when the
  schedule changes) and returns the next ``/joint_states`` message for the joint sampled after the
  request, with its sample stamp. Reads arrive in schedule order from the driver.
* ``wait_until`` waits on the node clock (ROS time, or /clock with use_sim_time).
"""
from __future__ import annotations

import collections
import threading

from hexapod_model.bus import BusError
from hexapod_model.contract import JOINT_COMMANDS, JOINT_STATES, READ_SCHEDULE


class RosBus:
    def __init__(self, node, t_com_s: float, read_timeout_s: float = 0.5):
        from hexapod_msgs.msg import ReadSchedule
        from sensor_msgs.msg import JointState
        self._JointState = JointState
        self._ReadSchedule = ReadSchedule
        self.node = node
        self.t_com_s = t_com_s
        self.read_timeout_s = read_timeout_s
        self._cv = threading.Condition()
        self._latest: dict[str, collections.deque] = collections.defaultdict(lambda: collections.deque(maxlen=64))
        self._schedule: tuple[str, ...] = ()
        self._cmd_pub = node.create_publisher(JointState, JOINT_COMMANDS, 10)
        self._sched_pub = node.create_publisher(ReadSchedule, READ_SCHEDULE, 10)
        node.create_subscription(JointState, JOINT_STATES, self._on_state, 100)
        self.stopped = threading.Event()

    # -- subscription callback (executor thread)
    def _on_state(self, msg) -> None:
        t = msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9
        with self._cv:
            for i, name in enumerate(msg.name):
                if i < len(msg.position):
                    self._latest[name].append((t, float(msg.position[i])))
            self._cv.notify_all()

    def now(self) -> float:
        return self.node.get_clock().now().nanoseconds * 1e-9

    def sync_write(self, goals_rad) -> float:
        msg = self._JointState()
        msg.header.stamp = self.node.get_clock().now().to_msg()
        msg.name = list(goals_rad)
        msg.position = [float(v) for v in goals_rad.values()]
        self._cmd_pub.publish(msg)
        return msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9

    def set_schedule(self, joints) -> None:
        joints = tuple(joints)
        if joints != self._schedule:
            m = self._ReadSchedule()
            m.header.stamp = self.node.get_clock().now().to_msg()
            m.joint_names = list(joints)
            self._sched_pub.publish(m)
            self._schedule = joints

    def read_position(self, joint: str) -> tuple[float, float]:
        if joint not in self._schedule and self._schedule:
            self.set_schedule(self._schedule + (joint,))
        requested = self.now()
        with self._cv:
            ok = self._cv.wait_for(lambda: self.stopped.is_set() or any(
                t >= requested - self.t_com_s for t, _ in self._latest[joint]), timeout=self.read_timeout_s)
            if self.stopped.is_set():
                raise BusError('locomotion stopped')
            if not ok:
                raise BusError(f'no /joint_states reading of {joint} within {self.read_timeout_s} s '
                               f'(is the driver or sim running and reading it?)')
            q = self._latest[joint]
            while q and q[0][0] < requested - self.t_com_s:
                q.popleft()
            t, pos = q.popleft()
        return pos, t

    def wait_until(self, t: float) -> None:
        while not self.stopped.is_set() and self.now() < t:
            self.stopped.wait(min(0.0005, max(t - self.now(), 0.0)))
