"""The servo bus as the controller sees it: a protocol that the MuJoCo sim, the bus emulator and
the ROS topic bridge all implement, so the locomotion library runs unchanged on each.

Time is explicit: every call returns the bus time at which it happened (seconds; sim time in the
sim, ROS time on the robot). A read is one transaction of ``t_com_s``; reads are sequential.

:class:`ServoBus` is what every caller needs. The capabilities that only some buses have are small
protocols of their own; an implementation names each one it implements among its bases (so a
reader sees at the class line what it offers), callers test for one with ``isinstance``, and
``tests/test_bus_protocols.py`` checks every implementation against its declaration:

======================  ==========================================================================
:class:`ServoBus`       ``t_com_s``, ``now``, ``sync_write``, ``read_position``, ``wait_until``
:class:`Scheduled`      ``set_schedule(joints)``: the joints the bus reads in turn between writes
:class:`Stoppable`      ``stopped`` (``threading.Event``): set, every further call raises BusError
:class:`MasterClocked`  a remote bus master's clock: ``time_hint()``, ``wait_for_master(log)``,
                        ``read_age_s`` (how old the last read was when it arrived)
:class:`SimulatedServos`  the plant's own view: ``sample_position`` (a read without its
                        transaction cost), ``servo_state()``, ``set_torque_enabled(on, joints)``
:class:`ReadsObserved`  ``observe_reads(callback)``: every position the bus master reads, its own
                        background reads included, handed to ``callback(names, positions, stamp)``
:class:`ImuObserved`    ``observe_imu(callback)``: every sample of the bus master's body IMU
                        (:class:`~hexapod_model.imu.ImuReading`), handed to ``callback(reading)``
======================  ==========================================================================
"""
from __future__ import annotations

import threading
from typing import TYPE_CHECKING, Callable, Mapping, Protocol, Sequence, runtime_checkable

if TYPE_CHECKING:
    from hexapod_model.imu import ImuReading


class BusError(RuntimeError):
    """A bus transaction failed (timeout, corrupt packet, missing servo) after its retry budget."""


@runtime_checkable
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


@runtime_checkable
class Scheduled(Protocol):
    def set_schedule(self, joints: Sequence[str]) -> object:
        """Read these joints in turn, one per read transaction, from now on."""


@runtime_checkable
class Stoppable(Protocol):
    stopped: threading.Event          # set: the bus refuses further calls (BusError)


@runtime_checkable
class MasterClocked(Protocol):
    read_age_s: float | None          # how long after the master published it the last read arrived [s]

    def time_hint(self) -> float | None:
        """The master's time now, without waiting for it (None before the first read)."""

    def wait_for_master(self, log: Callable[[str], None]) -> None:
        """Block until the bus master answers, saying why through ``log``."""


@runtime_checkable
class SimulatedServos(Protocol):
    def sample_position(self, joint: str) -> tuple[float, float]:
        """What a read of ``joint`` would report now, without spending ``t_com_s``."""

    def servo_state(self) -> object:
        """Temperatures and loads of every servo (the plant's thermal and load model)."""

    def set_torque_enabled(self, enabled: bool, joints: Sequence[str] | None = None) -> None:
        """Torque on or off for these joints (all when None)."""


@runtime_checkable
class ReadsObserved(Protocol):
    def observe_reads(self, callback: Callable[[Sequence[str], Sequence[float], float], None]) -> None:
        """Call ``callback(names, positions [rad], stamp [s])`` with every position the bus master reads
        from now on, its own background reads included: what it publishes on ``/joint_states``, handed
        over without a subscription to it (a controller composed with the bus master in one process paid
        a DDS round trip and an executor wake-up per read for it)."""



@runtime_checkable
class ImuObserved(Protocol):
    def observe_imu(self, callback: Callable[[ImuReading], None]) -> None:
        """Call ``callback(reading)`` with every sample of the bus master's body IMU from now on: what it
        publishes on ``/imu``, handed over without a subscription to it (the sim's 400 Hz IMU woke a
        composed controller's executor 400 times a second)."""


CAPABILITIES = (Scheduled, Stoppable, MasterClocked, SimulatedServos, ReadsObserved, ImuObserved)
