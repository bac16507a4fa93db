"""Fault injection of the emulated bus: dropped, corrupt and stale replies, adapter latency, replies
held back longer (a USB stall), a servo that disappears, overheating, overload and supply voltage."""
from __future__ import annotations

import random
from typing import ContextManager, Protocol, Sequence

from hexapod_driver.emulator.control_table import EmulatedServo, EmulatorError


class Emulated(Protocol):
    """What the faults act on: the emulated bus (:class:`hexapod_driver.emulator.pty_server.BusEmulator`)."""

    lock: ContextManager
    servos: Sequence[EmulatedServo]

    def servo(self, servo_id: int) -> EmulatedServo:
        """The servo with this id (EmulatorError if there is none)."""

    def _check_alarms(self, s: EmulatedServo) -> int:
        """Apply the alarm shutdown for the servo's persistent errors; returns the persistent error bits."""


class Faults:
    """Fault injection. Every method is thread-safe and takes effect on the next packet.

    ``ids`` = None means any servo. ``count`` faults happen on the next ``count`` matching
    replies; ``probability`` makes each matching reply fail at random (seeded).
    """

    def __init__(self, emulator: Emulated, seed: int):
        self._emu = emulator
        self._rng = random.Random(seed)
        self._drop: list[tuple[set[int] | None, int | None, float]] = []
        self._corrupt: list[tuple[set[int] | None, int | None, float]] = []
        self._stale: list[tuple[set[int] | None, int | None, float]] = []
        self._hold: list[tuple[set[int] | None, int | None, float, float, int | None]] = []   # ..., s, address
        self.missing: set[int] = set()
        self.temperature_override: dict[int, float] = {}   # servo id -> present temperature, over the backend's
        self._before_override: dict[int, float] = {}
        self.reply_latency_s = 0.0
        self.dropped = 0
        self.corrupted = 0
        self.stale = 0

    @staticmethod
    def _ids(ids) -> set[int] | None:
        if ids is None:
            return None
        return {int(ids)} if isinstance(ids, int) else {int(i) for i in ids}

    def drop_replies(self, ids=None, count: int | None = 1, probability: float = 1.0) -> tuple:
        """The next ``count`` replies (or each with ``probability`` if ``count`` is None) are lost.
        Returns the rule, for :meth:`cancel`."""
        rule = (self._ids(ids), count, probability)
        with self._emu.lock:
            self._drop.append(rule)
        return rule

    def corrupt_replies(self, ids=None, count: int | None = 1, probability: float = 1.0) -> tuple:
        """The next ``count`` replies get a wrong checksum byte. Returns the rule, for :meth:`cancel`."""
        rule = (self._ids(ids), count, probability)
        with self._emu.lock:
            self._corrupt.append(rule)
        return rule

    def cancel(self, rule: tuple) -> None:
        """End a rule of :meth:`drop_replies` / :meth:`corrupt_replies` / :meth:`stale_replies` made
        with ``count=None`` (a counted rule ends by itself); unknown rules are ignored."""
        with self._emu.lock:
            for rules in (self._drop, self._corrupt, self._stale, self._hold):
                if rule in rules:
                    rules.remove(rule)
                    return

    def stale_replies(self, ids=None, count: int | None = 1, probability: float = 1.0) -> None:
        """The next ``count`` replies are preceded by a stray empty status packet of the same servo, as
        when the reply to an earlier, timed-out instruction arrives late."""
        with self._emu.lock:
            self._stale.append((self._ids(ids), count, probability))

    def set_reply_latency(self, seconds: float) -> None:
        """Every reply reaches the host ``seconds`` later than the servo sent it, as behind an FTDI
        adapter whose latency timer is at its 16 ms default. Instructions are still executed on
        arrival (the host-to-servo direction is not held back)."""
        if not seconds >= 0:
            raise EmulatorError(f'reply latency must be >= 0, got {seconds}')
        with self._emu.lock:
            self.reply_latency_s = float(seconds)

    def hold_replies(self, seconds: float, ids=None, count: int | None = 1, probability: float = 1.0,
                     address: int | None = None) -> tuple:
        """The next ``count`` replies (or each with ``probability`` if ``count`` is None) reach the host
        ``seconds`` later than the latency alone brings them, as in a USB stall; the replies behind
        one wait for it (the adapter is a FIFO). ``address``: only replies to a READ or WRITE of
        that address. Returns the rule, for :meth:`cancel`."""
        if not seconds > 0:
            raise EmulatorError(f'hold must be > 0 s, got {seconds}')
        rule = (self._ids(ids), count, probability, float(seconds), address)
        with self._emu.lock:
            self._hold.append(rule)
        return rule

    def remove_servo(self, servo_id: int) -> None:
        """The servo disappears from the bus (cable cut): it neither answers nor executes."""
        with self._emu.lock:
            self._emu.servo(servo_id)
            self.missing.add(servo_id)

    def restore_servo(self, servo_id: int) -> None:
        with self._emu.lock:
            self.missing.discard(servo_id)

    def set_temperature(self, servo_id: int, temperature_c: float) -> None:
        """Present temperature; above the limit (address 11) it raises the overheating alarm."""
        with self._emu.lock:
            s = self._emu.servo(servo_id)
            s.temperature_c = float(temperature_c)
            self._emu._check_alarms(s)

    def override_temperature(self, servo_id: int, temperature_c: float | None) -> None:
        """Hold the present temperature at ``temperature_c`` whatever the backend's thermal model says
        (a hot spot the model does not have); None hands it back to the backend."""
        with self._emu.lock:
            s = self._emu.servo(servo_id)
            if temperature_c is None:
                if self.temperature_override.pop(servo_id, None) is not None:
                    s.temperature_c = self._before_override.pop(servo_id)   # a backend with a model overwrites it
                return
            self._before_override.setdefault(servo_id, s.temperature_c)
            self.temperature_override[servo_id] = float(temperature_c)
            s.temperature_c = float(temperature_c)
            self._emu._check_alarms(s)

    def set_overload(self, servo_id: int, active: bool = True) -> None:
        """The servo cannot hold its load (overload alarm) until cleared."""
        with self._emu.lock:
            s = self._emu.servo(servo_id)
            s.overload = bool(active)
            self._emu._check_alarms(s)

    def set_voltage(self, voltage_v: float, servo_id: int | None = None) -> None:
        with self._emu.lock:
            for s in ([self._emu.servo(servo_id)] if servo_id is not None else self._emu.servos):
                s.voltage_v = float(voltage_v)

    def clear(self) -> None:
        """Remove every pending drop/corrupt rule and restore missing servos."""
        with self._emu.lock:
            self._drop.clear()
            self._corrupt.clear()
            self._stale.clear()
            self._hold.clear()
            self.missing.clear()

    @staticmethod
    def _match(rules, rng, servo_id) -> bool:
        for i, (ids, count, prob) in enumerate(rules):
            if ids is not None and servo_id not in ids:
                continue
            if rng.random() >= prob:
                continue
            if count is not None:
                if count <= 1:
                    del rules[i]
                else:
                    rules[i] = (ids, count - 1, prob)
            return True
        return False

    def _hold_s(self, servo_id: int, address: int | None) -> float:
        for i, (ids, count, prob, seconds, at) in enumerate(self._hold):
            if (ids is not None and servo_id not in ids or at is not None and address != at
                    or self._rng.random() >= prob):
                continue
            if count is not None:
                if count <= 1:
                    del self._hold[i]
                else:
                    self._hold[i] = (ids, count - 1, prob, seconds, at)
            return seconds
        return 0.0

    def _should_drop(self, servo_id: int) -> bool:
        if self._match(self._drop, self._rng, servo_id):
            self.dropped += 1
            return True
        return False

    def _should_prepend_stale(self, servo_id: int) -> bool:
        if self._match(self._stale, self._rng, servo_id):
            self.stale += 1
            return True
        return False

    def _should_corrupt(self, servo_id: int) -> bool:
        if self._match(self._corrupt, self._rng, servo_id):
            self.corrupted += 1
            return True
        return False
