"""The servo bus seen through ROS topics: implements :class:`hexapod_model.bus.ServoBus` on top of
the driver's (or the sim node's) interface, so :class:`GaitController` runs unchanged behind the
locomotion node.

* ``sync_write`` publishes one ``/joint_commands`` message (stamped now).
* ``read_position(joint)`` asks the bus master for that joint (when the schedule changes) and
  returns the next ``/joint_states`` message for the joint sampled after the request, with its
  sample stamp. Reads arrive in schedule order from the driver.
* ``set_schedule`` calls the ``/set_read_schedule`` service and waits for its answer, so goals
  written afterwards are read back in the new order; a bus master without the service gets the
  ``/read_schedule`` topic instead (not in lock-step, which needs the ordering).
* Time is the bus master's: the stamps of its reads (sim time from the sim node, ROS time from
  the driver), whatever the node's own clock is. Writes are stamped on that time base too, so a
  read "sampled after the last write" means the same thing on both sides with default parameters
  (no use_sim_time needed). Between two reads the time runs on with the wall clock, for at most
  one read (``t_com_s``), so it never runs ahead of the master by more than that.
* ``wait_until`` waits until that time passes ``t``.
* ``read_age_s``: how long after the bus master published it the last read returned was taken
  (the DDS source timestamp against this computer's system clock; None when the middleware gives
  none). A backlog in the subscriber shows here: the locomotion node warns when it exceeds what
  Algorithm 1 tolerates (:mod:`hexapod_locomotion.core.read_timing`).
* ``lockstep``: the bus master (sim_node with ``lockstep:=true``) advances one read-schedule cycle
  per ``/joint_commands`` message; waiting and reading then publish empty commands to advance it,
  so a run does not depend on machine load. Every command is answered by exactly one cycle (the
  schedule's length in reads, known because the schedule is set through the service), and no new
  command goes out before all reads owed so far have arrived: the bus time is then exactly the
  master's time, however far the subscription lags behind the publisher.
"""
from __future__ import annotations

import collections
import threading
import time
from typing import Callable, Sequence

from rclpy.callback_groups import MutuallyExclusiveCallbackGroup

from hexapod_model.bus import BusError, MasterClocked, ReadsObserved, Scheduled, ServoBus, Stoppable
from hexapod_model.contract import JOINT_COMMANDS, JOINT_STATES, READ_SCHEDULE, SET_READ_SCHEDULE, stamp_parts, stamp_seconds
from hexapod_model.description import ALL_JOINTS


class RosBus(ServoBus, Scheduled, Stoppable, MasterClocked, ReadsObserved):
    def __init__(self, node, t_com_s: float, read_timeout_s: float = 0.5, lockstep: bool = False):
        from sensor_msgs.msg import JointState

        from hexapod_msgs.msg import ReadSchedule
        from hexapod_msgs.srv import SetReadSchedule
        self._JointState = JointState
        self._ReadSchedule = ReadSchedule
        self._SetReadSchedule = SetReadSchedule
        self.node = node
        self.t_com_s = t_com_s
        self.read_timeout_s = read_timeout_s
        self.lockstep = lockstep
        self._last_write = -1.0
        self._consumed: dict[str, float] = {}
        self._newest = None         # newest read stamp received: the bus time base
        self._newest_mono = 0.0     # monotonic wall time when it arrived
        self._now = -float('inf')   # bus time handed out last (never goes backwards)
        self._owed = 0              # lock-step: reads still to come for the commands sent so far
        self._cv = threading.Condition()
        # joint -> (stamp, position, DDS source timestamp [ns]) of its latest reads
        self._latest: dict[str, collections.deque] = collections.defaultdict(lambda: collections.deque(maxlen=64))
        self.read_age_s: float | None = None
        self._schedule: tuple[str, ...] = ()
        # deep queues: with a slow bus master (a loaded machine) a reliable writer's shallow history
        # would drop goals before they are acknowledged
        self._cmd_pub = node.create_publisher(JointState, JOINT_COMMANDS, 1000)
        self._sched_pub = node.create_publisher(ReadSchedule, READ_SCHEDULE, 10)
        self._sched_cli = node.create_client(SetReadSchedule, SET_READ_SCHEDULE)
        self._sched_service: bool | None = None     # unknown until the first schedule change
        # own callback group: a callback of the node that waits for reads can never starve this one
        node.create_subscription(JointState, JOINT_STATES, self._on_state, 1000,
                                 callback_group=MutuallyExclusiveCallbackGroup())
        self.stopped = threading.Event()
        self._observers: list[Callable] = []

    # -- subscription callback (executor thread)
    def _on_state(self, msg, info) -> None:
        t = stamp_seconds(msg.header.stamp)
        src = info.get('source_timestamp', 0) if info else 0
        with self._cv:
            for i, name in enumerate(msg.name):
                if i < len(msg.position):
                    self._latest[name].append((t, float(msg.position[i]), src))
            if self._newest is None or t > self._newest:
                self._newest, self._newest_mono = t, time.monotonic()
            self._owed = max(0, self._owed - 1)
            self._cv.notify_all()
        for cb in self._observers:
            cb(msg.name, msg.position, t)

    def observe_reads(self, callback: Callable[[Sequence[str], Sequence[float], float], None]) -> None:
        """``callback`` is called in the executor's thread, with each ``/joint_states`` message."""
        self._observers.append(callback)

    def now(self) -> float:
        """The bus master's time (see the module doc); waits for its first read if none came yet."""
        if self.lockstep and self._newest is None:
            self._advance()           # a lock-stepped master reads only when told: ask for the first cycle
        with self._cv:
            if self._newest is None and not self._cv.wait_for(
                    lambda: self._newest is not None or self.stopped.is_set(), timeout=self.read_timeout_s):
                raise BusError(f'no {self.node.resolve_topic_name(JOINT_STATES)} from a bus master within {self.read_timeout_s} s '
                               '(is the driver or sim node running?)')
            if self.stopped.is_set():
                raise BusError('locomotion stopped')
            if self.lockstep:
                # the bus master advances only on our commands: its time is the end of the last read
                # owed to us (/clock and the subscription queue can both lag behind it)
                self._settle()
                return self._newest + self.t_com_s
            return self._time_hint()

    def _time_hint(self) -> float:
        """Bus time from the newest read without waiting (called with _cv held)."""
        if self._newest is None:
            return self._now
        t = self._newest + self.t_com_s
        if not self.lockstep:
            t += min(time.monotonic() - self._newest_mono, self.t_com_s)
        self._now = max(self._now, t)
        return self._now

    def time_hint(self) -> float | None:
        """The bus time as far as known now, never blocking (for callbacks); None before the first read."""
        with self._cv:
            return None if self._newest is None else self._time_hint()

    def wait_for_master(self, log) -> None:
        """Block until a bus master is up: its schedule service answers, and in lock-step it also
        listens to our commands; otherwise its first read arrived. ``log(text)`` every 5 s meanwhile
        (a node started before the driver or sim node waits for it, as ROS clients wait for services)."""
        waited = 0.0
        while not self.stopped.is_set():
            if self.lockstep:
                if self._sched_cli.wait_for_service(timeout_sec=1.0) and self._cmd_pub.get_subscription_count():
                    return
            else:
                with self._cv:
                    if self._cv.wait_for(lambda: self._newest is not None or self.stopped.is_set(), timeout=1.0):
                        return
            waited += 1.0
            if waited % 5 == 0:
                log(f'waiting for a bus master ({self.node.resolve_topic_name(JOINT_STATES)}, '
                    f'{self.node.resolve_service_name(SET_READ_SCHEDULE)}): start the driver or sim node '
                    f'({waited:.0f} s)')
        raise BusError('locomotion stopped')

    # -- lock-step bookkeeping (called with _cv held)
    def _settle(self) -> None:
        """Wait until every read owed for the commands sent so far has arrived."""
        if not self._cv.wait_for(lambda: self._owed == 0 or self.stopped.is_set(), timeout=self.read_timeout_s):
            raise BusError(f'lock-step: {self._owed} reads of the last command did not arrive within '
                           f'{self.read_timeout_s} s (is sim_node running with lockstep:=true?)')
        if self.stopped.is_set():
            raise BusError('locomotion stopped')

    def _publish(self, msg) -> None:
        if self.lockstep:
            with self._cv:
                self._settle()
                self._owed += len(self._schedule or ALL_JOINTS)     # one schedule cycle per command
                self._cmd_pub.publish(msg)
        else:
            self._cmd_pub.publish(msg)

    def sync_write(self, goals_rad) -> float:
        msg = self._JointState()
        msg.header.stamp.sec, msg.header.stamp.nanosec = stamp_parts(self.now())     # the master's time base
        msg.name = list(goals_rad)
        msg.position = [float(v) for v in goals_rad.values()]
        self._publish(msg)
        self._last_write = stamp_seconds(msg.header.stamp)
        return self._last_write

    def _advance(self) -> None:
        """Lock-step: an empty command makes the bus master run one more read cycle; returns once
        that cycle's reads have all arrived."""
        msg = self._JointState()
        t = 0.0 if self._newest is None else self._newest + self.t_com_s
        msg.header.stamp.sec, msg.header.stamp.nanosec = stamp_parts(t)
        self._publish(msg)
        with self._cv:
            self._settle()

    def set_schedule(self, joints) -> None:
        joints = tuple(joints)
        if joints == self._schedule:
            return
        if self._sched_service is None:
            self._sched_service = self._sched_cli.wait_for_service(
                timeout_sec=self.read_timeout_s if self.lockstep else min(1.0, self.read_timeout_s))
            if not self._sched_service:
                if self.lockstep:
                    raise BusError(f'lock-step needs the {SET_READ_SCHEDULE} service of the bus master '
                                   f'(sim_node provides it); none answered within {self.read_timeout_s} s')
                self.node.get_logger().warning(f'no {self.node.resolve_service_name(SET_READ_SCHEDULE)} service: '
                                               f'sending {self.node.resolve_topic_name(READ_SCHEDULE)} '
                                               'messages (the first reads after a change may follow the old order)')
        if self._sched_service:
            if self.lockstep:
                with self._cv:
                    self._settle()            # the cycle in flight still follows the old schedule
            self._call_set_schedule(joints)
        else:
            m = self._ReadSchedule()
            m.header.stamp.sec, m.header.stamp.nanosec = stamp_parts(self.time_hint() or 0.0)
            m.joint_names = list(joints)
            self._sched_pub.publish(m)
        self._schedule = joints

    def _call_set_schedule(self, joints) -> None:
        done = threading.Event()
        fut = self._sched_cli.call_async(self._SetReadSchedule.Request(joint_names=list(joints)))
        fut.add_done_callback(lambda _: done.set())
        if not done.wait(self.read_timeout_s) and not fut.done():
            fut.cancel()
            raise BusError(f'{SET_READ_SCHEDULE} did not answer within {self.read_timeout_s} s')
        res = fut.result()
        if not res.success:
            raise BusError(f'read schedule {list(joints)} refused by the bus master: {res.message}')

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
        while True:
            with self._cv:
                if self.stopped.is_set():
                    raise BusError('locomotion stopped')
                if self.lockstep:
                    self._settle()
                got = self._fresh(joint)
                if got is not None:
                    self._latest[joint].clear()
                    self._consumed[joint] = got[0]
                    self.read_age_s = (time.time_ns() - got[2]) * 1e-9 if got[2] > 0 else None
                    return got[1], got[0]
                if time.monotonic() > deadline:
                    raise BusError(f'no /joint_states reading of {joint} within {self.read_timeout_s} s '
                                   f'(is the driver or sim running and reading it?)')
                if not self.lockstep:
                    self._cv.wait(timeout=0.005)
                    continue
                if self._newest is None:
                    self._cv.wait_for(lambda: self._newest is not None or self.stopped.is_set(),
                                      timeout=self.read_timeout_s)
                    continue
            self._advance()

    def wait_until(self, t: float) -> None:
        deadline = time.monotonic() + max(10.0, 100 * self.read_timeout_s)
        while not self.stopped.is_set() and self.now() < t:
            if time.monotonic() > deadline:
                raise BusError(f'bus time did not reach {t:.3f} s (clock at {self.now():.3f} s): is /clock published?')
            if self.lockstep:
                self._advance()
            else:
                self.stopped.wait(min(0.0005, max(t - self.now(), 0.0)))
