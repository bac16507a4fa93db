"""Faults that come and go on the emulated bus: a seeded random schedule, the thread that applies it,
and the record of every position the emulated servos reported.

* :func:`random_schedule` draws a schedule (pure: seed and duration in, :class:`FaultEvent` list
  out): dropped and corrupted replies, an overheating servo, a supply voltage outside the servos'
  limits, a servo that stops answering for a few seconds, the port that disappears and returns.
  The faults overlap as they come.
* :class:`ScheduleRunner` applies a schedule to a running :class:`~.pty_server.BusEmulator`
  through its :class:`~.faults.Faults` (times from when :meth:`ScheduleRunner.begin` is called) and
  writes one JSON line per fault start and end (wall-clock time, what, which servos).
* :class:`ReplyRecorder` appends every present position a servo sent (wall time, servo id, tick),
  every read or ping it left unanswered (tick :data:`UNANSWERED`) and every reply it sent corrupted (tick
  :data:`CORRUPTED`), to a binary file as it goes, so a checker can prove that each position a driver
  published was one a servo reported, and tell which injected faults touched a request (:func:`load_replies`).

``bus_emulator --fault-schedule FILE --events-out FILE --replies-out FILE`` wires them up.
"""
from __future__ import annotations

import json
import math
import random
import threading
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from hexapod_driver import protocol as p

if TYPE_CHECKING:
    from hexapod_driver.emulator.pty_server import BusEmulator

KINDS = ('drop', 'corrupt', 'overheat', 'voltage', 'silent', 'port')
PRESENT_POSITION = 36                      # address of present_position (2 bytes)
REPLY_ROW = 3                              # wall time, servo id, tick (float64 each)
UNANSWERED = -1                            # the tick of a row for a request that got no reply
CORRUPTED = -2                             # the tick of a row for a reply sent with a broken checksum


class ScheduleError(ValueError):
    """A fault schedule file that cannot be used; the message names the file and what is wrong."""


@dataclass(frozen=True)
class FaultEvent:
    """One fault: ``kind`` from ``start_s`` to ``start_s + duration_s`` (schedule time).

    ``ids``: the servos it affects (empty: every servo, or the port); ``value``: the reply loss
    probability (drop, corrupt), the temperature [deg C] (overheat) or the supply voltage [V]."""

    kind: str
    start_s: float
    duration_s: float
    ids: tuple[int, ...] = ()
    value: float = 0.0

    @property
    def end_s(self) -> float:
        return self.start_s + self.duration_s

    def describe(self) -> str:
        who = 'port' if self.kind == 'port' else (f'ids {list(self.ids)}' if self.ids else 'all servos')
        what = {'drop': f'replies dropped with p={self.value:g}', 'corrupt': f'replies corrupted with p={self.value:g}',
                'overheat': f'overheating at {self.value:g} C', 'voltage': f'supply at {self.value:g} V',
                'silent': 'not answering', 'port': 'port gone'}[self.kind]
        return f'{self.kind} {who}: {what} for {self.duration_s:.1f} s'


def random_schedule(seed: int, duration_s: float, *, servo_ids, quiet_ids=(), temperature_limit_c: float,
                    voltage_limits_v: tuple[float, float], first_s: float = 5.0, tail_s: float = 10.0,
                    mean_gap_s: float | None = None) -> list[FaultEvent]:
    """A seeded schedule over ``[first_s, duration_s - tail_s]``: every kind once per round, rounds
    in shuffled order, gaps random around ``mean_gap_s`` (default: six faults per 40 s of a short run,
    one per 20 s of a long one), durations a few seconds, so faults overlap now and then.

    ``quiet_ids``: the servos that may go silent (a controller that must read a servo at every
    step stops when it is silent for longer than its read timeout; the caller decides which).
    The last fault ends ``tail_s`` before the end, for the recovery to be seen."""
    servo_ids = sorted(int(i) for i in servo_ids)
    quiet = sorted(int(i) for i in quiet_ids) or servo_ids
    span = duration_s - tail_s - first_s
    if span <= 0:
        return []
    rng = random.Random(seed)
    gap = mean_gap_s if mean_gap_s is not None else min(20.0, max(3.0, span / 8.0))
    lo_v, hi_v = voltage_limits_v
    events: list[FaultEvent] = []
    t = first_s
    kinds: list[str] = []
    while True:
        if not kinds:
            kinds = list(KINDS)
            rng.shuffle(kinds)
        kind = kinds.pop()
        if kind in ('drop', 'corrupt'):
            n = rng.choice((1, 1, 2))
            ev = FaultEvent(kind, t, rng.uniform(2.0, 8.0), tuple(sorted(rng.sample(servo_ids, n))),
                            round(rng.uniform(0.05, 0.3), 3))
        elif kind == 'overheat':
            ev = FaultEvent(kind, t, rng.uniform(3.0, 8.0), (rng.choice(servo_ids),),
                            float(math.ceil(temperature_limit_c) + rng.randint(2, 8)))
        elif kind == 'voltage':
            v = rng.choice((lo_v - rng.uniform(0.3, 1.0), hi_v + rng.uniform(0.3, 1.5)))
            ev = FaultEvent(kind, t, rng.uniform(2.0, 6.0), (), round(v, 1))
        elif kind == 'silent':
            ev = FaultEvent(kind, t, rng.uniform(2.0, 5.0), (rng.choice(quiet),))
        else:
            ev = FaultEvent(kind, t, rng.uniform(0.3, 1.2))
        if ev.end_s > duration_s - tail_s:
            break
        events.append(ev)
        t += rng.uniform(0.4, 1.6) * gap
    return events


def dump_schedule(events: list[FaultEvent], path: str | Path) -> None:
    Path(path).write_text(json.dumps([asdict(e) for e in events], indent=1))


def load_schedule(path: str | Path) -> list[FaultEvent]:
    """Read a schedule written by :func:`dump_schedule`; a bad file raises :class:`ScheduleError`."""
    try:
        raw = json.loads(Path(path).read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ScheduleError(f'{path}: cannot read the fault schedule: {exc}') from None
    if not isinstance(raw, list):
        raise ScheduleError(f'{path}: a fault schedule is a JSON list of faults, got {type(raw).__name__}')
    out = []
    for k, item in enumerate(raw):
        try:
            ev = FaultEvent(str(item['kind']), float(item['start_s']), float(item['duration_s']),
                            tuple(int(i) for i in item.get('ids', ())), float(item.get('value', 0.0)))
        except (TypeError, KeyError, ValueError) as exc:
            raise ScheduleError(f'{path}: fault {k}: {type(exc).__name__}: {exc}') from None
        if ev.kind not in KINDS:
            raise ScheduleError(f'{path}: fault {k}: kind {ev.kind!r} is not one of {", ".join(KINDS)}')
        if not (math.isfinite(ev.start_s) and ev.start_s >= 0 and math.isfinite(ev.duration_s) and ev.duration_s > 0
                and math.isfinite(ev.value)):
            raise ScheduleError(f'{path}: fault {k}: start_s >= 0, duration_s > 0 and value must be finite numbers')
        out.append(ev)
    return out


class ScheduleRunner:
    """Applies ``events`` to ``emu`` from :meth:`begin` on; each start and end is a JSON line in
    ``events_out`` (``{"t": wall time, "phase": "start"|"end", "fault": k, ...the event}``)."""

    def __init__(self, emu: 'BusEmulator', events: list[FaultEvent], events_out: str | Path | None):
        self.emu = emu
        self.events = sorted(events, key=lambda e: e.start_s)
        self._out = open(events_out, 'a', buffering=1) if events_out else None
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._rules: dict[int, tuple] = {}
        self._write_lock = threading.Lock()

    def begin(self) -> None:
        if self._thread is None:
            self._thread = threading.Thread(target=self._run, args=(time.monotonic(),), name='fault-schedule',
                                            daemon=True)
            self._thread.start()

    def note(self, record: dict) -> None:
        if self._out is not None:
            with self._write_lock:
                self._out.write(json.dumps(dict(record, t=time.time())) + '\n')

    def _run(self, t0: float) -> None:
        actions = sorted([(e.start_s, 0, k) for k, e in enumerate(self.events)] +
                         [(e.end_s, 1, k) for k, e in enumerate(self.events)])
        self.note({'phase': 'schedule', 'faults': len(self.events)})
        for at, end, k in actions:
            if self._stop.wait(max(0.0, t0 + at - time.monotonic())):
                return
            ev = self.events[k]
            (self._end if end else self._start)(k, ev)
            self.note({'phase': 'end' if end else 'start', 'fault': k, **asdict(ev)})

    def _start(self, k: int, ev: FaultEvent) -> None:
        f = self.emu.faults
        if ev.kind == 'drop':
            self._rules[k] = f.drop_replies(ev.ids or None, count=None, probability=ev.value)
        elif ev.kind == 'corrupt':
            self._rules[k] = f.corrupt_replies(ev.ids or None, count=None, probability=ev.value)
        elif ev.kind == 'overheat':
            for i in ev.ids:
                f.override_temperature(i, ev.value)
        elif ev.kind == 'voltage':
            f.set_voltage(ev.value)
        elif ev.kind == 'silent':
            for i in ev.ids:
                f.remove_servo(i)
        elif ev.kind == 'port':
            self.emu.disconnect()

    def _end(self, k: int, ev: FaultEvent) -> None:
        f = self.emu.faults
        if ev.kind in ('drop', 'corrupt'):
            f.cancel(self._rules.pop(k))
        elif ev.kind == 'overheat':
            for i in ev.ids:
                f.override_temperature(i, None)
        elif ev.kind == 'voltage':
            f.set_voltage(self.emu.robot.servo.supply_voltage_v)
        elif ev.kind == 'silent':
            for i in ev.ids:
                f.restore_servo(i)
        elif ev.kind == 'port':
            self.emu.reconnect()

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)

    def close(self, final: dict | None = None) -> None:
        self.stop()
        if final is not None:
            self.note(final)
        if self._out is not None:
            self._out.close()
            self._out = None


def servo_registers(emu: 'BusEmulator') -> dict:
    """{'servos': [{id, torque_enable, torque_limit}]}: what the servos hold (the final record)."""
    with emu.lock:
        return {'phase': 'final', 'servos': [{'id': s.servo_id, 'torque_enable': s.get('torque_enable'),
                                              'torque_limit': s.get('torque_limit')} for s in emu.servos]}


class ReplyRecorder:
    """Appends each present position a servo sent to ``path``: rows of (wall time of the request,
    servo id, tick) as float64 (:data:`UNANSWERED` or :data:`CORRUPTED` for a read or ping without a
    reply the host can take), flushed every ``period_s`` from the emulator's transaction log (the
    log must hold what arrives in that time: give the emulator a ``log_size`` of some 10,000)."""

    def __init__(self, emu: 'BusEmulator', path: str | Path, period_s: float = 0.2):
        self.emu = emu
        self.period_s = period_s
        self._f = open(path, 'ab')
        self.rows = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name='reply-recorder', daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.wait(self.period_s):
            self.flush()

    def flush(self) -> None:
        log = self.emu.log
        with self.emu.lock:
            entries = [log.popleft() for _ in range(len(log))]
        rows = []
        for e in entries:
            if e.instruction in (p.READ, p.PING) and e.servo_id != p.BROADCAST_ID and (not e.replied or e.corrupted):
                rows.append((e.wall, e.servo_id, CORRUPTED if e.replied else UNANSWERED))   # silent, dropped; corrupt
                continue
            if e.instruction != p.READ or not e.replied or e.address is None:
                continue
            off = PRESENT_POSITION - e.address
            if off < 0 or off + 2 > len(e.reply_params):
                continue
            rows.append((e.wall, e.servo_id, p.u16(e.reply_params[off:off + 2])))
        if rows and self._f is not None:
            np.asarray(rows, dtype=np.float64).tofile(self._f)
            self._f.flush()
            self.rows += len(rows)

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2.0)
        self.flush()
        self._f.close()
        self._f = None


def load_replies(path: str | Path) -> np.ndarray:
    """The rows a :class:`ReplyRecorder` wrote: an (N, 3) array of wall time, servo id, tick
    (:data:`UNANSWERED` for a request without a reply, :data:`CORRUPTED` for a reply sent corrupted)."""
    data = np.fromfile(path, dtype=np.float64)
    return data[:len(data) // REPLY_ROW * REPLY_ROW].reshape(-1, REPLY_ROW)
