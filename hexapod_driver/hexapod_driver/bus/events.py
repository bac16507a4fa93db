"""What the driver has to say, as typed records: an :class:`Event` has a kind, a level and fields
(joint, servo id, register, values); :meth:`Event.text` renders the English line the node logs and
puts on /diagnostics. Tests and callers match kinds and fields, never the wording.

:class:`EventLog` queues events and throttles a repeating series (same key): repeats within
``throttle_s`` are counted, and the next event of the series (or its end) says how many there were.
"""
from __future__ import annotations

import enum
from collections import deque
from dataclasses import dataclass, field
from typing import Any, Callable, Mapping

INFO, WARN, ERROR = 'info', 'warn', 'error'


class EventKind(enum.Enum):
    """Every kind of event, with its level and the template of its text (fields by name)."""

    PORT_LOST = ('port_lost', ERROR, 'port lost: {reason}; torque state unknown (nothing reaches the servos); '
                 'reopening every {period_s} s')
    RECONNECTED = ('reconnected', INFO, '{device} reopened, servos verified and holding position')
    RECONNECT_FAILED = ('reconnect_failed', ERROR, 'reconnect failed: {reason}')
    TRANSACTION_FAILED = ('transaction_failed', ERROR, '{reason}')
    READ_FAILED = ('read_failed', WARN, '{joint} (id {servo_id}): read failed after {attempts} attempts '
                   '({reason}); no position reported')
    SERVO_MISSING = ('servo_missing', ERROR, '{joint} (id {servo_id}) stopped answering ({reason}); skipped, '
                     're-probed every {period_s} s')
    SERVO_ANSWERS = ('servo_answers', INFO, '{joint} (id {servo_id}) answers again')
    ERROR_BITS = ('error_bits', WARN, '{joint} (id {servo_id}) reports: {errors}')
    ERROR_BITS_CLEARED = ('error_bits_cleared', INFO, '{joint} (id {servo_id}): error bits cleared')
    FAULT = ('fault', ERROR, '{joint} (id {servo_id}) {state}')
    RECOVERED = ('recovered', INFO, '{joint} (id {servo_id}) recovered: alarm cleared, torque limit '
                 '{torque_limit} restored (read back)')
    HOLDING = ('holding', WARN, 'no command for {idle_s:.2f} s (command_timeout_s={timeout_s}): holding '
               '{held} joints at their present positions')
    CLOCK_JUMPED = ('clock_jumped', WARN, 'clock jumped back by {by_s:.3f} s (to {now:.3f} s): read pacing, '
                    'diagnostics, reopen and command timeouts restart from the new time')
    CLOCK_PAUSED = ('clock_paused', WARN, 'the clock is not advancing (at {now:.3f} s for {wall_s:.1f} s of wall '
                    'time: use_sim_time with a paused /clock?): reads wait for it')
    CLOCK_RESUMED = ('clock_resumed', INFO, 'the clock advances again (at {now:.3f} s)')
    LATE_REPLIES = ('late_replies', WARN, "replies arrive ~{late_ms:.0f} ms late (the fastest of {pings} PING "
                    "round trips {rtt_ms:.1f} ms, wire time {wire_us:.0f} us): the USB adapter's latency timer is probably "
                    "at its 16 ms default. Set the adapter's latency_timer to 1 (udev rule, see "
                    'docs/real-robot.md). Until then every read waits for it: reply timeout widened from '
                    'latency_timer_ms={old_ms:g} to {new_ms:.1f}')
    NO_READ_REPLIES = ('no_read_replies', WARN, 'servo id {servo_id} answers PING but not READ (status return '
                       'level 0?): status return level (address 16) set to {value}')
    STATUS_RETURN_LEVEL_SET = ('status_return_level_set', WARN, '{joint} (id {servo_id}): status return level '
                               'was {was} ({meaning}); set to {value} (EEPROM) so that every write is confirmed')
    GOAL_OUTSIDE_LIMITS = ('goal_outside_limits', WARN, '{joint} (id {servo_id}) is at tick {tick}, outside its '
                           'angle limits [{low}, {high}]: goal set to {goal}, the joint will move there')

    def __init__(self, tag: str, level: str, template: str):
        self.tag, self.level, self.template = tag, level, template


@dataclass(frozen=True)
class Event:
    """One event: ``kind``, the values its text names (``fields``) and, for a throttled series,
    how many repeats it summarises (``repeats``: within the last ``window_s``, or before the
    series ``ended``)."""

    kind: EventKind
    fields: Mapping[str, Any] = field(default_factory=dict)
    repeats: int = 0
    window_s: float = 0.0
    ended: bool = False

    @property
    def level(self) -> str:
        return self.kind.level

    @property
    def joint(self) -> str | None:
        return self.fields.get('joint')

    @property
    def servo_id(self) -> int | None:
        return self.fields.get('servo_id')

    def text(self) -> str:
        """The English line (log, /diagnostics)."""
        out = self.kind.template.format(**self.fields)
        if self.repeats and self.ended:
            out += f' (repeated {self.repeats} more times before it stopped)'
        elif self.repeats:
            out += f' (and {self.repeats} more times in the last {self.window_s:g} s)'
        return out

    def log_line(self) -> str:
        """The text with its kind in front, so a log can be searched by kind."""
        return f'[{self.kind.tag}] {self.text()}'


class EventLog:
    """The queue of events not yet handed out, with the throttling of repeated series."""

    def __init__(self, clock: Callable[[], float], throttle_s: float = 5.0, maxlen: int = 1000):
        self.clock = clock
        self.throttle_s = throttle_s
        self._queue: deque[Event] = deque(maxlen=maxlen)
        self._series: dict[str, list] = {}     # key -> [window start, suppressed count, last event]

    def emit(self, kind: EventKind, key: str | None = None, **fields) -> None:
        """Queue an event. With a ``key``, repeats within ``throttle_s`` are counted instead of
        queued and summarised by the next one after the window or by :meth:`end`."""
        ev = Event(kind, fields)
        if key is not None:
            now = self.clock()
            series = self._series.get(key)
            if series is not None and now - series[0] < self.throttle_s:
                series[1] += 1
                series[2] = ev
                return
            if series is not None and series[1]:
                ev = Event(kind, fields, repeats=series[1], window_s=self.throttle_s)
            self._series[key] = [now, 0, ev]
        self._queue.append(ev)

    def end(self, key: str) -> None:
        """The series ``key`` is over: say how many repeats were not queued."""
        series = self._series.pop(key, None)
        if series is not None and series[1]:
            last = series[2]
            self._queue.append(Event(last.kind, last.fields, repeats=series[1], ended=True))

    def drain(self) -> list[Event]:
        out = list(self._queue)
        self._queue.clear()
        return out
