"""The bus loop, one :meth:`BusLoop.step` at a time: reopen a lost port, write pending goals, hold
position when commands stop, read the next joint of the schedule, one diagnostics read when a
round is due (interleaved, one servo per step, so they never block the position reads for long).

Reads are paced (``read_period_s``) but goals are written the moment they arrive. A clock that
jumps back (sim time reset) or stands still (a paused /clock) is noticed and said once.
"""
from __future__ import annotations

import math
import time
from contextlib import AbstractContextManager
from dataclasses import dataclass, field, replace
from typing import Mapping, Protocol, runtime_checkable

from hexapod_driver.bus.commands import Commands
from hexapod_driver.bus.events import Event, EventKind
from hexapod_driver.bus.host import BusHost
from hexapod_driver.bus.policy import ServoPolicy
from hexapod_driver.bus.state import Sample, ServoState
from hexapod_driver.bus.transport import PortLostError
from hexapod_driver.protocol import u16
from hexapod_model.bus import BusError

CLOCK_JUMP_S = 0.05                   # a clock going back by more than this has jumped (sim reset, clock set)
CLOCK_PAUSE_S = 2.0                   # wall seconds without the clock advancing before it is called paused


@dataclass
class StepResult:
    """What one bus-loop step produced, for the node to publish."""

    samples: list[Sample] = field(default_factory=list)
    diagnostics: list[ServoState] | None = None
    events: list[Event] = field(default_factory=list)
    wrote: bool = False


@runtime_checkable
class LoopHost(BusHost, Protocol):
    """What :class:`BusLoop` uses of its bus (:class:`~hexapod_driver.bus.core.DynamixelBus`)."""

    commands: Commands
    policy: ServoPolicy
    estopped: bool
    lock: AbstractContextManager

    @property
    def port_ok(self) -> bool: ...

    def open_and_configure(self, enable_torque: bool) -> None: ...

    def write_goals(self, goals: Mapping[str, int]) -> float: ...


class BusLoop:
    """The loop's timing state (next read, diagnostics round, reopen) and its step."""

    def __init__(self, bus: LoopHost):
        self.bus = bus
        self.config = bus.config
        self.commands = bus.commands
        self.events = bus.events
        self.next_read_t = -math.inf
        self._diag_queue: list[str] = []
        self._next_diag_t = -math.inf
        self.next_reconnect_t = -math.inf
        self._clock_seen: tuple[float, float] | None = None   # (clock, monotonic wall time) it last changed
        self.clock_paused = False
        self.loss_reported = False             # the loss of the port now lost was reported

    def step(self) -> StepResult:
        bus = self.bus
        res = StepResult()
        # read pacing: wait for the next read slot, but write goals the moment they arrive
        while self.config.read_period_s > 0 and bus.port_ok:
            now = bus.clock()
            self.watch_clock(now)
            left = self.next_read_t - now
            if left <= 0:
                break
            if self.commands.arrived.wait(min(left, 0.05)):
                self.commands.arrived.clear()
                with bus.lock:
                    self._guarded(lambda: self._write_pending(res))
            if self.clock_paused:           # back to the caller now and then: it may be stopping
                res.events = self.events.drain()
                return res
        now = bus.clock()
        self.watch_clock(now)
        with bus.lock:
            if not bus.port_ok:
                if now >= self.next_reconnect_t:
                    self.next_reconnect_t = now + self.config.reconnect_period_s
                    self._reconnect()
                if not bus.port_ok:
                    res.events = self.events.drain()
                    bus.sleep(0.005)
                    return res
            self._guarded(lambda: (self._write_pending(res), self._check_stale(now), self._read_next(res, now),
                                   self._diagnostics_step(res, now)))
        res.events = self.events.drain()
        return res

    def watch_clock(self, now: float) -> None:
        """Notice a clock that jumps back (sim time reset, a system clock set back) and one that stands
        still (use_sim_time with a paused /clock): one event each. After a jump back, the times the
        loop waits for (next read, diagnostics round, reopen, the watchdog's last transaction, the
        command timeout) restart from the new time instead of waiting for the clock to catch up."""
        wall = time.monotonic()
        seen = self._clock_seen
        if seen is not None and now < seen[0] - CLOCK_JUMP_S:
            self.events.emit(EventKind.CLOCK_JUMPED, by_s=seen[0] - now, now=now)
            self.next_read_t = min(self.next_read_t, now)
            self._next_diag_t = min(self._next_diag_t, now)
            self.next_reconnect_t = min(self.next_reconnect_t, now)
            self.bus.transport.last_ok_t = min(self.bus.transport.last_ok_t, now)
            self.commands.clock_jumped(now)
        if seen is None or now != seen[0]:
            if self.clock_paused:
                self.clock_paused = False
                self.events.emit(EventKind.CLOCK_RESUMED, now=now)
            self._clock_seen = (now, wall)
        elif not self.clock_paused and wall - seen[1] >= CLOCK_PAUSE_S:
            self.clock_paused = True
            self.events.emit(EventKind.CLOCK_PAUSED, now=now, wall_s=wall - seen[1])

    def _guarded(self, fn) -> None:
        """Run bus work; a lost port or a failed transaction becomes an event, never an exception."""
        try:
            fn()
        except PortLostError as exc:
            self.port_lost(exc)
        except BusError as exc:
            self.events.emit(EventKind.TRANSACTION_FAILED, reason=str(exc))

    def port_lost(self, exc: Exception) -> None:
        """The port failed (in the bus loop or under a controller's read or write): one event per
        loss, every servo not responding, the next reopen one ``reconnect_period_s`` away."""
        bus = self.bus
        bus.transport.port_ok = False
        for st in bus.states.values():
            st.responding = False
        if self.loss_reported:
            return
        self.loss_reported = True
        self.events.emit(EventKind.PORT_LOST, reason=str(exc), period_s=self.config.reconnect_period_s)
        self.next_reconnect_t = bus.clock() + self.config.reconnect_period_s

    def _reconnect(self) -> None:
        bus = self.bus
        try:
            bus.open_and_configure(enable_torque=not bus.estopped)   # goals = present positions: no jump
            self.commands.clear()
            self.events.end('reconnect')
            self.events.emit(EventKind.RECONNECTED, device=self.config.device)
        except BusError as exc:
            bus.transport.close()
            self.events.emit(EventKind.RECONNECT_FAILED, key='reconnect', reason=str(exc))

    def _write_pending(self, res: StepResult) -> None:
        goals = self.commands.take_pending()
        if goals and not self.bus.estopped:
            self.bus.write_goals(goals)
            res.wrote = True

    def _check_stale(self, now: float) -> None:
        bus = self.bus
        idle = self.commands.stale_for(now)
        if idle is None or bus.estopped:
            return
        self.commands.holding = True
        hold = {}
        for j in bus.joints:
            st = bus.states[j]
            if st.missing or st.faulted:
                continue
            data = bus.read_register(j, 36, 2, retries=0).data
            if data is not None:
                hold[j] = u16(data)
        if hold:
            bus.write_goals(hold)
        self.events.emit(EventKind.HOLDING, idle_s=idle, timeout_s=self.config.command_timeout_s, held=len(hold))

    def _read_next(self, res: StepResult, now: float) -> None:
        policy = self.bus.policy
        sched, start = self.commands.next_reads()
        for k in range(len(sched)):
            joint = sched[(start + k) % len(sched)]
            if not policy.due(joint, now):
                continue
            if k:
                self.commands.skipped(sched, start, k)
            s = policy.read_joint(joint, retries=policy.retries(joint))
            if s is not None:
                res.samples.append(s)
                self.next_read_t = s.stamp + self.config.read_period_s
            return
        self.bus.sleep(0.001)               # every scheduled servo is missing: do not spin

    def _diagnostics_step(self, res: StepResult, now: float) -> None:
        if not self._diag_queue:
            if now < self._next_diag_t:
                return
            self._next_diag_t = now + self.config.diagnostics_period_s
            self._diag_queue = list(self.bus.joints)
        joint = self._diag_queue.pop(0)
        if self.bus.policy.due(joint, now):
            self.bus.policy.read_diagnostics(joint)
        if not self._diag_queue:
            res.diagnostics = [replace(self.bus.states[j]) for j in self.bus.joints]
