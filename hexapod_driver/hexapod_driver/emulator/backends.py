"""What moves the emulated servos' horns: the :class:`ServoBackend` protocol, the built-in
:class:`IdealServoBackend`, the :class:`ServoBusBackend` adapter over any
:class:`hexapod_model.bus.ServoBus`, and the plug-in group through which other packages add
backends to ``bus_emulator --backend NAME`` (hexapod_sim adds ``sim``, the MuJoCo hexapod).

A plug-in is an entry point in the group :data:`BACKEND_GROUP` whose object has ``help`` (one
line for ``--help``), ``add_arguments(group)`` (its own command-line options, on an argparse
argument group) and ``create(robot, args) -> ServoBackend``. The driver never imports a plug-in's
package: it only looks the group up, so the dependency points from the plug-in to the driver.
"""
from __future__ import annotations

import math
from importlib.metadata import entry_points
from typing import Callable, Mapping, Protocol

from hexapod_model.bus import ServoBus, SimulatedServos
from hexapod_model.description import ALL_JOINTS, Robot
from hexapod_model.servo import servo_theta, servo_tick

BACKEND_GROUP = 'hexapod_driver.emulator_backends'


def backend_plugins() -> dict:
    """{name: entry point} of the installed backend plug-ins (loaded only when chosen)."""
    return {ep.name: ep for ep in entry_points(group=BACKEND_GROUP)}


class ServoBackend(Protocol):
    """What moves the servo horns. ``slot`` is the physical servo (index into ALL_JOINTS), ``t``
    emulator time [s]; ticks are raw servo ticks."""

    def goals(self, t: float, goals: Mapping[int, int]) -> None: ...

    def torque(self, t: float, slot: int, enabled: bool) -> None: ...

    def sample(self, t: float, slot: int) -> tuple[float, float]:
        """(present tick, signed speed in ticks/s) at time ``t``."""

    def status(self, slot: int) -> tuple[float | None, float | None]:
        """(temperature [deg C], load fraction) when the backend models them, else None."""


def firmware_tick_at_or_after(t: float, period: float) -> int:
    return int(math.ceil(t / period - 1e-9))


class IdealServoBackend:
    """Servos that move straight to their goal at a constant speed on the firmware grid.

    ``speed_ticks_per_s(slot)`` is asked at every goal write (the emulator passes the moving
    speed register). No gravity: a limp servo stays where it is.
    """

    def __init__(self, robot: Robot, initial_ticks: Mapping[int, float] | None = None):
        self.period = robot.servo.control_period_s
        self.max_tick = robot.servo.max_tick
        center = float(robot.servo.center_tick)
        n = len(ALL_JOINTS)
        init = dict(initial_ticks or {})
        self._pos = [float(init.get(s, center)) for s in range(n)]   # position at tick self._k
        self._k = [0] * n
        self._goal = list(self._pos)
        self._enabled = [False] * n
        self._rate = [0.0] * n                                       # ticks per firmware period
        self.speed_ticks_per_s: Callable[[int], float] = lambda slot: 0.0

    def _advance(self, slot: int, k: int) -> None:
        if k <= self._k[slot]:
            return
        if self._enabled[slot]:
            err = self._goal[slot] - self._pos[slot]
            step = self._rate[slot] * (k - self._k[slot])
            self._pos[slot] += math.copysign(min(abs(err), step), err)
        self._k[slot] = k

    def goals(self, t: float, goals: Mapping[int, int]) -> None:
        k = firmware_tick_at_or_after(t, self.period) - 1    # the old goal acts until tick k
        for slot, tick in goals.items():
            self._advance(slot, k)
            self._goal[slot] = float(tick)
            self._rate[slot] = self.speed_ticks_per_s(slot) * self.period

    def torque(self, t: float, slot: int, enabled: bool) -> None:
        self._advance(slot, firmware_tick_at_or_after(t, self.period) - 1)
        self._enabled[slot] = enabled
        self._rate[slot] = self.speed_ticks_per_s(slot) * self.period

    def sample(self, t: float, slot: int) -> tuple[float, float]:
        k = int(math.floor(t / self.period + 1e-9))
        self._advance(slot, k)
        moving = self._enabled[slot] and abs(self._goal[slot] - self._pos[slot]) > 0
        speed = math.copysign(self._rate[slot] / self.period, self._goal[slot] - self._pos[slot]) if moving else 0.0
        return self._pos[slot], speed

    def status(self, slot: int) -> tuple[float | None, float | None]:
        return None, None          # no thermal or load model: the emulator's own values apply


class ServoBusBackend:
    """Adapter: the emulated servos are the joints of a :class:`ServoBus` (e.g. the MuJoCo sim).

    Emulator time ``t`` maps to bus time ``t0 + t`` (``t0`` = the bus's ``now()`` when the adapter
    was made). A goal write is ``wait_until`` + ``sync_write``; a sample is ``wait_until`` +
    ``sample_position`` where the bus has it (HexapodSim: the position a read reports, without
    the ``t_com_s`` an in-process read costs, so the physics keeps to the emulator's clock however
    often the driver reads: the pseudo-terminal's round trip is the read's cost here), else
    ``read_position``. With ``max_catch_up_s`` set (the sim plug-in sets it), a request
    never waits for more than that much physics: a real servo answers within microseconds, so when
    the host is too busy for the physics to keep up with the wall clock, the reply comes from
    slightly older physics (which catches up while the bus idles, or ``max_catch_up_s`` per
    request) rather than after the driver's timeout. Torque enable is forwarded when the bus has
    ``set_torque_enabled(enabled, joints)`` (HexapodSim); otherwise the simulated servos stay
    powered. When the bus has ``servo_state()`` (HexapodSim), its temperatures and loads are what
    the emulated servos report, so the sim's thermal model can raise the overheating alarm.
    """

    def __init__(self, bus: ServoBus, robot: Robot, max_catch_up_s: float | None = None):
        self.bus = bus
        self.robot = robot
        self.max_catch_up_s = math.inf if max_catch_up_s is None else float(max_catch_up_s)
        # Warm up before the clock starts: a JIT-compiled sim compiles on its first read/state
        # call, which must not happen while a driver waits for a reply.
        bus.read_position(ALL_JOINTS[0])
        self.plant = bus if isinstance(bus, SimulatedServos) else None
        if self.plant is not None:
            self.plant.servo_state()
        self.t0 = bus.now()
        self._joints = list(ALL_JOINTS)
        self._mount = [robot.bus.by_joint(j) for j in self._joints]
        self._last: dict[int, tuple[float, float]] = {}
        self._sample = bus.read_position if self.plant is None else self.plant.sample_position

    def _catch_up(self, t: float) -> None:
        self.bus.wait_until(min(self.t0 + t, self.bus.now() + self.max_catch_up_s))

    def goals(self, t: float, goals: Mapping[int, int]) -> None:
        self._catch_up(t)
        self.bus.sync_write({self._joints[s]: float(servo_theta(tick, self.robot.servo, self._mount[s]))
                             for s, tick in goals.items()})

    def idle(self, t: float) -> None:
        """Keep the simulated bus in step with the emulator's clock while nobody talks to it, one
        ``max_catch_up_s`` slice per idle poll (every 0.5 ms), so a request arriving meanwhile is not
        kept waiting."""
        self._catch_up(t)

    def torque(self, t: float, slot: int, enabled: bool) -> None:
        if self.plant is not None:
            self._catch_up(t)
            self.plant.set_torque_enabled(bool(enabled), [self._joints[slot]])

    def status(self, slot: int) -> tuple[float | None, float | None]:
        if self.plant is None:
            return None, None
        st = self.plant.servo_state()
        return float(st.temperature_c[slot]), float(st.load_fraction[slot])

    def sample(self, t: float, slot: int) -> tuple[float, float]:
        self._catch_up(t)
        theta, ts = self._sample(self._joints[slot])
        tick = float(servo_tick(theta, self.robot.servo, self._mount[slot]))
        speed = 0.0
        prev = self._last.get(slot)
        if prev is not None and ts > prev[1]:
            speed = (tick - prev[0]) / (ts - prev[1])
        self._last[slot] = (tick, ts)
        return tick, speed
