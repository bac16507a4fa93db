"""What every layer that works on the bus holding it uses of that bus
(:class:`~hexapod_driver.bus.core.DynamixelBus`); each layer's own protocol adds what only it uses."""
from __future__ import annotations

from typing import Callable, Mapping, Protocol, runtime_checkable

from hexapod_driver.bus.events import EventLog
from hexapod_driver.bus.state import ServoState
from hexapod_driver.bus.transport import ReadResult, Transport
from hexapod_driver.config import DriverConfig


@runtime_checkable
class BusHost(Protocol):
    """The bus's parameters, port, event log, joints and their states, clock, and register access."""

    config: DriverConfig
    transport: Transport
    events: EventLog
    joints: tuple[str, ...]
    states: Mapping[str, ServoState]
    clock: Callable[[], float]
    sleep: Callable[[float], None]

    def read_register(self, joint: str, address: int, n: int, retries: int | None = None) -> ReadResult: ...

    def write_register(self, joint: str, address: int, data: list[int]) -> None: ...
