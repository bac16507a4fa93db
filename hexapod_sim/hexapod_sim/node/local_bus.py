"""The simulated bus for a controller in the same process as the sim node, in real time. No rclpy.

Over DDS, the controller cannot keep Algorithm 1's cadence: every read is a message from one Python
process to another, and a command only takes effect after its own trip back (measured in
docs/architecture.md). On the robot, the loop that reads the femurs, compares and writes runs on
the computer that owns the serial bus; :class:`LocalSimBus` is the same arrangement for the
simulated robot: the controller calls the :class:`~hexapod_sim.node.bus_master_loop.SimBusLoop` directly (one
read = one transaction of ``t_com_s``), and every transaction's outputs (``/joint_states`` per read,
``/joint_commands`` per write, ``/clock``, IMU, power, diagnostics, truth) go to ``emit``, which
the sim node publishes and records as if a remote controller had driven it.

Real time: :class:`Pacer` keeps simulated time at ``real_time_factor`` x wall time. A transaction
that comes early waits for the wall clock (a real bus transaction takes its time); one that comes
late, because the controller computed in between, first lets the physics run idle to the wall
clock (a real bus idles while the computer thinks). So t_con in the stamps is what the robot would
see with this computer: L x T_com plus the controller's own time per control step.
``real_time_factor`` 0 runs as fast as possible (no pacing, deterministic like the in-process demo).
"""
from __future__ import annotations

import math
import threading
import time
from dataclasses import dataclass
from typing import Callable, Mapping, Sequence

from hexapod_model.bus import BusError, ImuObserved, ReadsObserved, Scheduled, ServoBus, Stoppable
from hexapod_model.imu import ImuReading
from hexapod_sim.node.bus_master_loop import JointSample, SimBusLoop
from hexapod_sim.physics.plant import SimError

IDLE_CHUNK_S = 0.002          # background reads are run in slices this long (sim time), lock released between


@dataclass(frozen=True)
class CommandSample:
    """A sync write made by the in-process controller (``/joint_commands``)."""
    t_s: float
    goals_rad: dict


@dataclass(frozen=True)
class ScheduleSample:
    """The in-process controller changed the read schedule (recorded as ``/read_schedule``)."""
    t_s: float
    joint_names: tuple


class Pacer:
    """Simulated time = anchor + rtf x (wall time since the anchor); rtf 0 = as fast as possible."""

    def __init__(self, rtf: float, sim_now: Callable[[], float], clock: Callable[[], float] = time.monotonic,
                 max_lag_s: float = 0.5):
        if not math.isfinite(rtf) or rtf < 0:
            raise SimError(f'real_time_factor must be >= 0 (0 = as fast as possible), got {rtf!r}')
        self.rtf = float(rtf)
        self.sim_now = sim_now
        self.clock = clock
        self.max_lag_s = max_lag_s
        self.reanchor()

    def reanchor(self, rtf: float | None = None) -> None:
        if rtf is not None:
            self.rtf = float(rtf)
        self._wall0, self._sim0 = self.clock(), self.sim_now()

    def target(self) -> float | None:
        """The simulated time due now, or None when not pacing."""
        if self.rtf <= 0:
            return None
        return self._sim0 + self.rtf * (self.clock() - self._wall0)

    def wall_wait_s(self, sim_t: float) -> float:
        """Wall seconds until simulated time ``sim_t`` is due (<= 0: due already)."""
        target = self.target()
        return 0.0 if target is None else (sim_t - target) / self.rtf


class LocalSimBus(ServoBus, Scheduled, Stoppable, ReadsObserved, ImuObserved):
    """:class:`hexapod_model.bus.ServoBus` over a :class:`SimBusLoop` in the caller's thread, paced."""

    def __init__(self, loop: SimBusLoop, emit: Callable[[list], None], pacer: Pacer, lock: threading.RLock,
                 sleep: Callable[[float], None] = time.sleep, on_lag: Callable[[float], None] | None = None):
        self.loop = loop
        self.sim = loop.sim
        self.t_com_s = self.sim.t_com_s
        self.emit = emit
        self.pacer = pacer
        self.lock = lock
        self.sleep = sleep
        self.on_lag = on_lag
        self.stopped = threading.Event()
        self._started = False
        self._observers: list[Callable] = []
        self._imu_observers: list[Callable] = []

    def _enter(self) -> None:
        """Before a transaction: wait for the wall clock if early; if late, let the bus idle to now."""
        if self.stopped.is_set():
            raise BusError('locomotion stopped')
        if not self._started:
            self._started = True
            self.pacer.reanchor()           # time spent starting the process is not the bus's
        wait = self.pacer.wall_wait_s(self.sim.now())
        if wait > 0:
            self.sleep(wait)
            return
        target = self.pacer.target()
        if target is None:
            return
        behind = target - self.sim.now()
        if behind > self.pacer.max_lag_s:          # the physics cannot keep up: do not try to catch up
            self.pacer.reanchor()
            if self.on_lag is not None:
                self.on_lag(behind)
        elif behind >= self.sim.dt:
            with self.lock:
                self.loop.idle(target)

    # -- ServoBus
    def now(self) -> float:
        return self.sim.now()

    def sync_write(self, goals_rad: Mapping[str, float]) -> float:
        self._enter()
        with self.lock:
            t = self.loop.command(goals_rad)
            self.emit([CommandSample(t, dict(goals_rad))])
        return t

    def read_position(self, joint: str) -> tuple[float, float]:
        self._enter()
        with self.lock:
            events = self.loop.read(joint)
            self.emit(events)
        self._observe(events)
        sample = next(e for e in events if isinstance(e, JointSample))
        return sample.theta_rad, sample.t_s

    def _observe(self, events) -> None:
        for e in events:
            if isinstance(e, JointSample):
                for cb in self._observers:
                    cb((e.joint,), (e.theta_rad,), e.t_s)
            elif isinstance(e, ImuReading):
                for cb in self._imu_observers:
                    cb(e)

    def wait_until(self, t: float) -> None:
        """Background reads per the schedule until ``t``, paced (as a driver's idle bus does)."""
        while self.sim.now() < t - 1e-12:
            self._enter()
            with self.lock:
                events = self.loop.run(until_s=min(t, self.sim.now() + IDLE_CHUNK_S))
                self.emit(events)
            self._observe(events)

    def set_schedule(self, joints: Sequence[str]) -> None:
        with self.lock:
            self.loop.set_schedule(joints)
            self.emit([ScheduleSample(self.sim.now(), self.loop.schedule)])

    def observe_reads(self, callback: Callable[[Sequence[str], Sequence[float], float], None]) -> None:
        self._observers.append(callback)

    def observe_imu(self, callback: Callable[[ImuReading], None]) -> None:
        self._imu_observers.append(callback)
