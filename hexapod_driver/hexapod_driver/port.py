"""The serial port under the driver: dynamixel-sdk's port handler made fit for 1 ms reads, and the
raw file-descriptor helpers of the bus's transport (:mod:`hexapod_driver.bus.transport`). No ROS import."""
from __future__ import annotations

import fcntl
import math
import os
import select
import struct
import termios
import time
from typing import Callable

from dynamixel_sdk import PortHandler


class LowLatencyPortHandler(PortHandler):
    """dynamixel-sdk's port handler without its 16 ms latency assumption and without busy polling.

    * The stock handler sizes every reply timeout as ``2 * 16 ms + 2 ms``, the FTDI default latency
      timer. With the adapter's latency_timer at 1 ms (udev rule) the timeout is
      ``bytes * 10 bits / baud + 2 * latency_timer_ms + margin_ms``, so a lost reply costs ~4 ms.
    * The stock ``readPort`` returns at once with whatever is buffered (``timeout=0``) and the
      packet handler spins on it: a 100 % CPU loop. Here it waits in ``select`` until a byte
      arrives or the packet deadline passes.
    * ``writePort`` records ``clock()`` just before the instruction goes out: the sample stamp.
    """

    def __init__(self, port_name: str, latency_timer_ms: float = 1.0, margin_ms: float = 2.0,
                 clock: Callable[[], float] = time.time):
        super().__init__(port_name)
        self.latency_timer_ms = float(latency_timer_ms)
        self.margin_ms = float(margin_ms)
        self.clock = clock
        self.last_tx_time = math.nan

    def setPacketTimeout(self, packet_length):  # noqa: N802 (SDK API)
        self.packet_start_time = self.getCurrentTime()
        self.packet_timeout = (self.tx_time_per_byte * packet_length) + 2.0 * self.latency_timer_ms + self.margin_ms

    def writePort(self, packet):  # noqa: N802
        self.last_tx_time = self.clock()
        return self.ser.write(packet)

    def readPort(self, length):  # noqa: N802
        if not self.ser.in_waiting:
            left_ms = self.packet_start_time + self.packet_timeout - self.getCurrentTime()
            if left_ms > 0:
                select.select([self.ser.fd], [], [], left_ms / 1000.0)
        return self.ser.read(length)


def in_waiting(fd: int) -> int:
    """Bytes waiting in the port's input buffer (TIOCINQ), without pyserial's overhead."""
    return struct.unpack('I', fcntl.ioctl(fd, termios.TIOCINQ, b'\0\0\0\0'))[0]


def write_all(fd: int, data: bytes) -> None:
    view = memoryview(data)
    while view:
        n = os.write(fd, view)
        view = view[n:]
