"""The servo bus as the controller sees it: a protocol that the MuJoCo sim, the bus emulator and
the ROS topic bridge all implement, so the locomotion library runs unchanged on each.

Time is explicit: every call returns the bus time at which it happened (seconds; sim time in the
sim, ROS time on the robot). A read is one transaction of ``t_com_s``; reads are sequential.
"""
from __future__ import annotations

from typing import Mapping, Protocol


class BusError(RuntimeError):
    """A bus transaction failed (timeout, corrupt packet, missing servo) after its retry budget."""


class ServoBus(Protocol):
    t_com_s: float

    def now(self) -> float:
        """Current bus time [s]."""

    def sync_write(self, goals_rad: Mapping[str, float]) -> float:
        """Send goal angles (joint name -> theta [rad]) in one transaction; returns its time."""

    def read_position(self, joint: str) -> tuple[float, float]:
        """Read one joint: (theta [rad] as reported by the servo, sample time [s]). Costs t_com_s."""

    def wait_until(self, t: float) -> None:
        """Let the bus idle until time ``t`` (no-op if already past)."""
