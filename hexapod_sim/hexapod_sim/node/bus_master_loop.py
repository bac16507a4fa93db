"""What the sim node does between ROS callbacks, as a plain class (no rclpy): the bus master loop.

The real driver owns the bus and runs a loop: sync-write goals when a command arrives, then read
positions one servo at a time in the order of the read schedule, cyclically. :class:`SimBusLoop`
does the same against :class:`hexapod_sim.physics.plant.HexapodSim` and returns, for every read, the
outputs due by the new simulated time, each with its simulated stamp:

* :class:`JointSample` per read (the ``/joint_states`` message; stamp = sample time),
* :class:`~hexapod_model.imu.ImuReading` at the IMU rate,
* :class:`PowerSample` (battery voltage, current and power averaged over the period),
* :class:`~hexapod_sim.physics.readings.ServoTelemetry` (diagnostics), :class:`BusTimingSample`,
* :class:`TruthSample` (evaluation-only foot contacts/forces and body pose),
* :class:`ClockTick` (``/clock``).

Pacing is the caller's business: :meth:`SimBusLoop.run` stops at a simulated time or after a
number of reads. In lock-step mode the node grants one schedule cycle per received command.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Mapping, Sequence

import numpy as np

from hexapod_model.description import ALL_JOINTS, LEGS
from hexapod_sim.physics.plant import HexapodSim, PowerMeter, SimError
from hexapod_sim.physics.readings import FootContacts, ServoTelemetry
from hexapod_sim.physics.truth_log import TruthLog


@dataclass(frozen=True)
class JointSample:
    joint: str
    theta_rad: float
    t_s: float            # sample time (start of the read transaction)


@dataclass(frozen=True)
class PowerSample:
    t_s: float
    voltage_v: float
    current_a: float      # drawn from the battery, averaged over the period (positive)
    power_w: float        # averaged over the period
    energy_j: float       # since the start


@dataclass(frozen=True)
class BusTimingSample:
    t_s: float
    reads: int            # read transactions since the previous sample
    writes: int
    t_com_s: float
    t_write_s: float


@dataclass(frozen=True)
class TruthSample:
    t_s: float
    contacts: FootContacts
    position_m: np.ndarray
    quat_wxyz: np.ndarray
    joint_angles_rad: np.ndarray | None = None     # true angles of ALL_JOINTS (for TF)


@dataclass(frozen=True)
class ClockTick:
    t_s: float


IMU_POLL_S = 0.02             # IMU samples are collected every 20 ms of simulated time while running
IMU_MIN_BATCH = 8             # ... and at the end of run() once at least this many are complete


def _stamp_of(ev) -> float:
    return ev.t_s


class _Every:
    """Fires at t = 0, p, 2p, ... (simulated time); ``due(t)`` -> the latest firing time <= t, once."""

    def __init__(self, period_s: float, what: str):
        if not math.isfinite(period_s) or period_s < 0:
            raise SimError(f'{what} must be >= 0 seconds (0 = off), got {period_s!r}')
        self.period = period_s
        self.next_t = 0.0 if period_s > 0 else math.inf

    def due(self, t: float) -> float | None:
        if t < self.next_t - 1e-12:
            return None
        k = math.floor(t / self.period + 1e-9)
        self.next_t = (k + 1) * self.period
        return k * self.period


class SimBusLoop:
    """Bus master over a :class:`HexapodSim`: cyclic reads per the schedule, writes on command."""

    def __init__(self, sim: HexapodSim, *, power_period_s: float = 0.01, diagnostics_period_s: float = 0.1,
                 timing_period_s: float = 1.0, truth_period_s: float = 0.01, clock_period_s: float = 0.001,
                 truth_log: TruthLog | None = None):
        self.sim = sim
        self.truth_log = truth_log          # the benchmarks' per-ms truth, sampled after every read
        self._power = _Every(power_period_s, 'power_period_s')
        self._diag = _Every(diagnostics_period_s, 'diagnostics_period_s')
        self._timing = _Every(timing_period_s, 'timing_period_s')
        self._truth = _Every(truth_period_s, 'truth_period_s')
        self._clock = _Every(clock_period_s, 'clock_period_s')
        self._power_meter = PowerMeter(sim)
        self._last_counts = dict(sim.bus_stats)
        self._imu_poll = _Every(IMU_POLL_S, 'IMU poll period')
        self._timers = (self._power, self._diag, self._timing, self._truth, self._clock, self._imu_poll)
        self._next_due = 0.0
        self.schedule: tuple[str, ...] = ALL_JOINTS
        self._pos = 0

    # -- inputs
    def set_schedule(self, joint_names: Sequence[str]) -> None:
        """Read these joints cyclically from the next read on; empty = all 18 in order."""
        names = tuple(joint_names)
        for n in names:
            if n not in ALL_JOINTS:
                raise SimError(f'read schedule: unknown joint {n!r}; joints are leg<1..6>_<coxa|femur|tibia>')
        self.schedule = names or ALL_JOINTS
        self._pos = 0

    def command(self, goals_rad: Mapping[str, float]) -> float:
        """Sync-write goals now (an empty mapping writes nothing); returns the write time."""
        if not goals_rad:
            return self.sim.now()
        return self.sim.sync_write(goals_rad)

    @property
    def cycle_reads(self) -> int:
        """Reads in one cycle of the schedule."""
        return len(self.schedule)

    # -- running
    def run(self, until_s: float | None = None, max_reads: int | None = None) -> list:
        """Read (per the schedule) until simulated time reaches ``until_s`` or ``max_reads`` reads are done.

        Returns the outputs due, sorted by their stamps. IMU samples (exact stamps) are collected
        every ``IMU_POLL_S`` while running and at the end once ``IMU_MIN_BATCH`` are complete, so
        they are published at most ~20 ms of simulated time late. With ``until_s`` the last read
        may end up to ``t_com`` past it.
        """
        if until_s is None and max_reads is None:
            raise SimError('run(): give until_s and/or max_reads')
        out: list = []
        reads = 0
        while True:
            if max_reads is not None and reads >= max_reads:
                break
            if until_s is not None and self.sim.now() >= until_s - 1e-12:
                break
            joint = self.schedule[self._pos]
            self._pos = (self._pos + 1) % len(self.schedule)
            self._read(joint, out)
            reads += 1
        return self._finish(out)

    def read(self, joint: str) -> list:
        """One read of ``joint`` now, outside the schedule (a controller that owns the bus); returns
        the outputs due, sorted by stamp, the :class:`JointSample` among them."""
        if joint not in ALL_JOINTS:
            raise SimError(f'unknown joint {joint!r}; joints are leg<1..6>_<coxa|femur|tibia>')
        out: list = []
        self._read(joint, out)
        return self._finish(out)

    def idle(self, until_s: float) -> None:
        """The bus idles (no transaction) until ``until_s``: a controller that owns the bus is computing.
        The physics runs on, and the benchmarks' truth (:attr:`truth_log`) keeps its rows."""
        log = self.truth_log
        if log is None:
            self.sim.wait_until(until_s)
            return
        while self.sim.now() < until_s - 1e-12:
            self.sim.wait_until(min(until_s, self.sim.now() + log.period_s))
            log.sample(self.sim)

    def _read(self, joint: str, out: list) -> None:
        theta, t = self.sim.read_position(joint)
        out.append(JointSample(joint, theta, t))
        if self.truth_log is not None:
            self.truth_log.sample(self.sim)
        self._periodic(out)

    def _finish(self, out: list) -> list:
        out.extend(self.sim.pop_imu_samples(IMU_MIN_BATCH))
        out.sort(key=_stamp_of)
        return out

    def _periodic(self, out: list) -> None:
        sim = self.sim
        now = sim.now()
        if now < self._next_due - 1e-12:
            return
        self._periodic_due(out, now)
        self._next_due = min(t.next_t for t in self._timers)

    def _periodic_due(self, out: list, now: float) -> None:
        sim = self.sim
        if self._imu_poll.due(now) is not None:
            out.extend(sim.pop_imu_samples())
        if self._clock.due(now) is not None:
            out.append(ClockTick(now))
        if self._power.due(now) is not None:
            b = self._power_meter.sample()
            out.append(PowerSample(now, b.voltage_v, b.current_a, b.power_w, b.energy_j))
        if self._diag.due(now) is not None:
            out.append(sim.servo_state())
        if self._truth.due(now) is not None:
            pos, quat = sim.body_pose()
            out.append(TruthSample(now, sim.foot_contacts(), pos, quat, sim.true_joint_angles()))
        if self._timing.due(now) is not None:
            c = dict(sim.bus_stats)
            out.append(BusTimingSample(now, c['reads'] - self._last_counts['reads'],
                                       c['writes'] - self._last_counts['writes'], sim.t_com_s, sim.t_write_s))
            self._last_counts = c


def truth_vector(contacts: FootContacts) -> list[float]:
    """Flat layout of ``/sim/foot_contacts``: 6 contact flags (0/1), then fx, fy, fz per leg [N]."""
    return [float(x) for x in contacts.in_contact] + [float(v) for v in contacts.force_world_n.ravel()]


TRUTH_LAYOUT = (('contact', len(LEGS)), ('force_xyz', 3 * len(LEGS)))
__all__ = ['SimBusLoop', 'JointSample', 'PowerSample', 'BusTimingSample', 'TruthSample', 'ClockTick',
           'ServoTelemetry', 'truth_vector', 'TRUTH_LAYOUT']
