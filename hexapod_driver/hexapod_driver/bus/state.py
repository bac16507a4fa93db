"""What the bus's layers pass between them: a position read (:class:`Sample`), what the driver knows
of one servo (:class:`ServoState`)."""
from __future__ import annotations

import math
from dataclasses import dataclass


@dataclass(frozen=True)
class Sample:
    """One position read: what the servo returned, stamped at the start of the transaction."""

    joint: str
    theta_rad: float
    tick: int
    stamp: float          # time the READ instruction was written [s, driver clock]
    t_com_s: float        # duration of the transaction (write to complete status packet)
    error_bits: int


@dataclass
class ServoState:
    """What the driver knows about one servo (the ServoStatus message)."""

    joint: str
    servo_id: int
    responding: bool = True
    missing: bool = False
    consecutive_failures: int = 0
    last_probe: float = -math.inf
    error_bits: int = 0
    torque_enabled: bool = False
    torque_limit: int | None = 0    # register 34 as last read (None: unknown)
    temperature_c: float = math.nan
    voltage_v: float = math.nan
    load_fraction: float = math.nan
    present_tick: int | None = None
    failed_attempts: int = 0        # read attempts without a valid reply, since start-up
    faulted: int = 0                # alarm bits that triggered the fault policy (0 = no fault)
    message: str = ''

