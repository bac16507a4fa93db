"""Commands and the read schedule: what the bus loop is asked to write and in which order to read.

:class:`Commands` validates goals (unknown joint, NaN/inf, outside the joint limits: clamped or
rejected by ``limit_policy``; stale stamps rejected), keeps the goals not yet written and the
time of the last command (the hold on a silent command stream), and the read schedule with its
cursor. Thread-safe: the node's callbacks set, the bus loop takes.
"""
from __future__ import annotations

import math
import threading
from dataclasses import dataclass
from typing import Callable, Iterable, Mapping, Sequence

from hexapod_model.description import DescriptionError, Robot, parse_joint_name


class CommandError(ValueError):
    """A command or read schedule was rejected; the message names the joint and the reason."""


ESTOP_TEXT = 'emergency stop is active: torque is off; restart (or deactivate and activate) the driver to re-enable'


@dataclass(frozen=True)
class Validated:
    """Goals in raw ticks, and the warnings validation gave (clamped goals)."""

    goals_tick: dict[str, int]
    warnings: list[str]


class Commands:
    def __init__(self, robot: Robot, joints: Sequence[str], to_tick: Callable[[str, float], int],
                 limit_policy: str, command_timeout_s: float, clock: Callable[[], float]):
        self.robot = robot
        self.joints = tuple(joints)
        self.to_tick = to_tick
        self.limit_policy = limit_policy
        self.timeout_s = command_timeout_s
        self.clock = clock
        self.lock = threading.Lock()
        self.arrived = threading.Event()       # set when goals are pending
        self._pending: dict[str, int] = {}
        self.last_command_t: float | None = None
        self.holding = False                   # the command stream went silent: holding position
        self.schedule: tuple[str, ...] = self.joints
        self._cursor = 0

    def check_joint(self, joint: str) -> None:
        if joint not in self.joints:
            try:
                parse_joint_name(joint)
            except DescriptionError as exc:
                raise CommandError(f'unknown joint {joint!r}: {exc}') from None
            raise CommandError(f'unknown joint {joint!r}')

    def validate_goals(self, goals_rad: Mapping[str, float]) -> Validated:
        """Goals -> raw ticks. Unknown names and non-finite values reject the whole command; values
        outside the joint limits are clamped (with a warning) or rejected, per ``limit_policy``."""
        if not goals_rad:
            raise CommandError('empty command: no joint goals')
        out, warnings = {}, []
        for joint, theta in goals_rad.items():
            self.check_joint(joint)
            try:
                theta = float(theta)
            except (TypeError, ValueError):
                raise CommandError(f'{joint}: goal {theta!r} is not a number') from None
            if not math.isfinite(theta):
                raise CommandError(f'{joint}: goal {theta} is not finite; command rejected')
            lo, hi = self.robot.joint_limits(joint)
            if not lo <= theta <= hi:
                if self.limit_policy == 'reject':
                    raise CommandError(f'{joint}: goal {theta:.4f} rad outside the joint limits [{lo}, {hi}]; '
                                       f'command rejected')
                clamped = min(hi, max(lo, theta))
                warnings.append(f'{joint}: goal {theta:.4f} rad outside [{lo}, {hi}], clamped to {clamped}')
                theta = clamped
            out[joint] = self.to_tick(joint, theta)
        return Validated(out, warnings)

    def set_command(self, names: Sequence[str], positions: Sequence[float], stamp: float | None,
                    faulted: Mapping[str, str]) -> list[str]:
        """Queue goals for the next step; joints in ``faulted`` (joint -> why) are left out with a
        warning. Raises :class:`CommandError` (nothing queued) for a malformed, stale or rejected command."""
        if len(names) != len(positions):
            raise CommandError(f'{len(names)} joint names but {len(positions)} positions')
        if len(set(names)) != len(names):
            raise CommandError(f'duplicate joint names in command: {list(names)}')
        now = self.clock()
        timeout = self.timeout_s
        if stamp and timeout > 0 and now - stamp > timeout:
            raise CommandError(f'stale command: stamped {now - stamp:.3f} s ago (command_timeout_s={timeout})')
        v = self.validate_goals(dict(zip(names, positions)))
        warnings = list(v.warnings)
        goals = {}
        for j, tick in v.goals_tick.items():
            if j in faulted:
                warnings.append(f'{j}: ignored, servo in fault ({faulted[j]})')
                continue
            goals[j] = tick
        with self.lock:
            self._pending.update(goals)
            self.last_command_t = now
        self.arrived.set()
        return warnings

    def take_pending(self) -> dict[str, int]:
        """The goals not yet written (and forget them); a new command ends a hold."""
        with self.lock:
            goals, self._pending = self._pending, {}
            if goals:
                self.holding = False
        return goals

    def clear(self) -> None:
        with self.lock:
            self._pending.clear()

    def stale_for(self, now: float) -> float | None:
        """Seconds without a command once that exceeds ``command_timeout_s`` and no hold is on; else None."""
        last = self.last_command_t
        if self.timeout_s <= 0 or last is None or self.holding or now - last <= self.timeout_s:
            return None
        return now - last

    def clock_jumped(self, now: float) -> None:
        if self.last_command_t is not None:
            self.last_command_t = min(self.last_command_t, now)

    # ------------------------------------------------------------------ the read schedule
    def set_schedule(self, names: Iterable[str]) -> tuple[str, ...]:
        """Set the read order (empty = all 18 joints). Unknown names reject the whole schedule."""
        names = tuple(names)
        for n in names:
            self.check_joint(n)
        with self.lock:
            self.schedule = names or self.joints
            self._cursor = 0
        return self.schedule

    def next_reads(self) -> tuple[tuple[str, ...], int]:
        """(schedule, start): the joints to try in order from ``start``; the cursor moves on by one."""
        with self.lock:
            sched, start = self.schedule, self._cursor
            self._cursor = (start + 1) % len(sched)
        return sched, start

    def skipped(self, sched: tuple[str, ...], start: int, k: int) -> None:
        """The read went to ``sched[start + k]`` (the ones before were skipped): continue after it."""
        with self.lock:
            if self.schedule is sched:
                self._cursor = (start + k + 1) % len(sched)
