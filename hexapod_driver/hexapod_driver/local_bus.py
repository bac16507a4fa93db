"""The AX-12A bus for a controller composed in the driver's process (the robot executable). No rclpy.

Over DDS between Python processes the read-decide-write loop of Algorithm 1 cannot hold
t_con = L x T_com (docs/architecture.md). On the robot, the computer that owns the serial port runs
that loop: :class:`LocalDriverBus` hands the driver's :class:`~hexapod_driver.bus.DynamixelBus` to
the controller's thread, which then *is* the bus loop. Every read and write still leaves through
the node (``/joint_states`` per read, ``/joint_commands`` per write), so a recording of the composed
robot reads like one of the separate processes.

While the controller waits (``wait_until``), the bus keeps doing what the driver's own loop does
between commands: reads per the schedule, a diagnostics round when due, reconnecting a lost port.
"""
from __future__ import annotations

import threading
from typing import Callable, Mapping, Sequence

from hexapod_driver.bus import DynamixelBus, PortLostError, StepResult
from hexapod_model.bus import BusError, ReadsObserved, Scheduled, ServoBus, Stoppable


class LocalDriverBus(ServoBus, Scheduled, Stoppable, ReadsObserved):
    """:class:`hexapod_model.bus.ServoBus` over a :class:`DynamixelBus`, called in the caller's thread.

    ``on_read(joint, theta, stamp)``, ``on_write(stamp, goals_rad)`` and ``on_step(StepResult)``
    are the node's publishers; they run in the controller's thread. The driver's events (a servo
    that stopped answering, a fault) are logged by ``on_step`` at the next idle moment."""

    def __init__(self, core: DynamixelBus, on_read: Callable[[str, float, float], None],
                 on_write: Callable[[float, dict], None], on_step: Callable[[StepResult], None],
                 read_timeout_s: float = 2.0):
        self.core = core
        self.read_timeout_s = float(read_timeout_s)
        self.t_com_s = core.t_com_s
        self.on_read, self.on_write, self.on_step = on_read, on_write, on_step
        self.stopped = threading.Event()
        self._observers: list[Callable] = []

    def _check(self) -> None:
        if self.stopped.is_set():
            raise BusError('locomotion stopped')

    # -- ServoBus
    def now(self) -> float:
        return self.core.now()

    def sync_write(self, goals_rad: Mapping[str, float]) -> float:
        t_end = self.core.now() + self.read_timeout_s
        while True:
            self._check()
            try:
                t = self.core.sync_write(goals_rad)
                break
            except PortLostError:
                if self.core.now() >= t_end:
                    raise
                self._while_port_lost()
        self.on_write(t, dict(goals_rad))
        return t

    def read_position(self, joint: str) -> tuple[float, float]:
        """One read; a failed one (after the driver's retries) is tried again until
        ``read_timeout_s``, as a controller over topics waits that long for a reading."""
        t_end = self.core.now() + self.read_timeout_s
        while True:
            self._check()
            try:
                theta, stamp = self.core.read_position(joint)
                break
            except BusError:
                if self.core.now() >= t_end:
                    raise
                self._while_port_lost()
        self.on_read(joint, theta, stamp)
        for cb in self._observers:
            cb((joint,), (theta,), stamp)
        return theta, stamp

    def _step(self) -> None:
        """One step of the driver's own loop, published, its reads observed."""
        res = self.core.step()
        self.on_step(res)
        for s in res.samples:
            for cb in self._observers:
                cb((s.joint,), (s.theta_rad,), s.stamp)

    def _while_port_lost(self) -> None:
        """A lost port is reopened by the driver's loop (every ``reconnect_period_s``): run a step of
        it, which also reports the loss, rather than failing the controller while the adapter is
        away for less than ``read_timeout_s``."""
        if not self.core.port_ok:
            self._step()

    def wait_until(self, t: float) -> None:
        """The driver's own loop until ``t``: scheduled reads, diagnostics, reconnects.

        A step first waits for its read slot (``read_period_s`` after the last read, the
        controller's femur reads included) and then takes up to ``t_com_s``; it is started only if
        it ends by ``t``, so the controller's next write is never delayed by a background read."""
        while not self.stopped.is_set() and max(self.core.now(), self.core.next_read_t) + self.t_com_s <= t:
            self._step()
        self.core.wait_until(t)

    def set_schedule(self, joints: Sequence[str]) -> None:
        self.core.set_schedule(joints)

    def observe_reads(self, callback: Callable[[Sequence[str], Sequence[float], float], None]) -> None:
        self._observers.append(callback)
