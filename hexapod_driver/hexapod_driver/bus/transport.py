"""The transport layer: the serial port and Protocol 1.0 framing, nothing about servos or policy.

:class:`Transport` opens and closes the port (:class:`~hexapod_driver.port.LowLatencyPortHandler`
for its timing), sends instruction packets and waits for the status packet that answers them,
framed by the same :class:`hexapod_driver.protocol.PacketParser` the bus emulator uses. On top
of one exchange (:meth:`Transport.transact`) it offers a register read and write with a given
number of attempts; how many is the caller's policy.

Pairing replies with requests (Protocol 1.0 has no sequence numbers): bytes waiting before an
instruction goes out are discarded (as dynamixel-sdk's ``clearPort``); a reply must have the ID and
the LENGTH of the status packet its instruction asks for; and while a request is unanswered (timed
out, its reply perhaps still on its way), no READ of that servo asks for its length, so a reply
later than every attempt of a read is never taken for the answer to the next read.

Stamps: the sample time of a read is the time its instruction packet was written to the port
(the start of the transaction), taken from the injected ``clock``; T_com is the time from that
write to the complete status packet.
"""
from __future__ import annotations

import contextlib
import math
import os
import select
import time
from dataclasses import dataclass, field
from typing import Callable

import serial
from dynamixel_sdk import COMM_RX_CORRUPT, COMM_RX_TIMEOUT, COMM_SUCCESS

from hexapod_driver import protocol as p
from hexapod_driver.port import LowLatencyPortHandler, in_waiting, write_all
from hexapod_model.bus import BusError

ALARM_BITS = p.ERR_OVERHEATING | p.ERR_OVERLOAD
BITS_TIMES_1000 = p.BITS_PER_BYTE * 1000.0


class PortLostError(BusError):
    """The serial port vanished or failed (unplugged adapter, I/O error)."""


def result_text(result: int) -> str:
    """A dynamixel-sdk COMM_* result in words."""
    return {COMM_RX_TIMEOUT: 'no reply (timeout)', COMM_RX_CORRUPT: 'corrupt reply'}.get(result, f'result {result}')


@dataclass
class ReadResult:
    """A register read: ``data`` (None after every attempt failed), the stamp and duration of the
    transaction that answered, its error bits, and one reason per failed attempt."""

    data: bytes | None = None
    stamp: float = math.nan
    t_com_s: float = math.nan
    error_bits: int = 0
    failures: list[str] = field(default_factory=list)


class Transport:
    """One serial port speaking Protocol 1.0. Not thread-safe: the caller holds its lock."""

    def __init__(self, device: str, baud_rate: int, latency_timer_ms: float, timeout_margin_ms: float,
                 clock: Callable[[], float] = time.time):
        self.device = device
        self.baud_rate = int(baud_rate)
        self.latency_timer_ms = latency_timer_ms
        self.timeout_margin_ms = timeout_margin_ms
        self.clock = clock
        self.port: LowLatencyPortHandler | None = None
        self.port_ok = False
        self.last_ok_t = -math.inf                 # clock() of the last answered transaction (watchdog)
        self._parser = p.PacketParser()
        self._skipped = 0                          # bytes of whole packets that answered something else
        self._packets: dict[tuple, bytes] = {}     # encoded READ instructions (the hot path)
        # servo id -> data lengths of its status packets asked for, never received, since the bus
        # last answered: one of them may still come, so no READ asks for that length meanwhile
        self._unanswered: dict[int, set[int]] = {}

    @property
    def stale_bytes(self) -> int:
        """Bytes discarded as not answering the request they arrived during."""
        return self._skipped + self._parser.discarded_bytes

    # ------------------------------------------------------------------ the port
    def open(self) -> None:
        """(Re)open the port; PortLostError when it cannot be."""
        self.close()
        port = LowLatencyPortHandler(self.device, self.latency_timer_ms, self.timeout_margin_ms, clock=self.clock)
        try:
            if not port.setBaudRate(self.baud_rate):
                raise PortLostError(f'{self.device}: baud rate {self.baud_rate} is not supported by the port handler')
        except (serial.SerialException, OSError) as exc:
            raise PortLostError(f'cannot open {self.device}: {exc}') from None
        self.port = port
        self.port_ok = True
        self._skipped += self._parser.clear()
        self._unanswered.clear()

    def close(self) -> None:
        if self.port is not None and self.port.ser is not None:
            try:
                self.port.closePort()
            except (serial.SerialException, OSError):
                pass
        self.port = None
        self.port_ok = False

    @contextlib.contextmanager
    def reply_margin(self, margin_ms: float):
        """A wider reply timeout for a while (start-up on a noisy bus)."""
        if self.port is not None:
            self.port.margin_ms = max(self.timeout_margin_ms, margin_ms)
        try:
            yield
        finally:
            if self.port is not None:
                self.port.margin_ms = self.timeout_margin_ms

    @property
    def last_tx_time(self) -> float:
        return self.port.last_tx_time if self.port is not None else math.nan

    def _require_port(self) -> LowLatencyPortHandler:
        if self.port is None or not self.port_ok:
            raise PortLostError(f'{self.device} is not open')
        return self.port

    # ------------------------------------------------------------------ one exchange
    def transact(self, sid: int, instruction: int, params: list[int], n_reply: int,
                 expect_reply: bool = True) -> tuple[bytes, int, int]:
        """One instruction/status exchange: (data, result, error); result is a dynamixel-sdk COMM_* code.

        Bytes already waiting before the instruction goes out are stale (the late reply to an
        earlier, timed-out transaction) and are discarded. A reply is accepted only if it answers
        this instruction: the right ID, the LENGTH this instruction's status packet has
        (``n_reply`` data bytes + 2) and a valid checksum; any other packet is skipped and the wait
        goes on until the reply timeout. A corrupt reply of the right ID and length ends the wait
        (COMM_RX_CORRUPT) so the caller can retry at once. A timeout leaves the request unanswered
        (:meth:`reply_length` keeps READs away from its length) until any request is answered:
        the adapter delivers replies in the order the servos sent them.
        """
        port = self._require_port()
        key = (sid, instruction, tuple(params))
        pkt = self._packets.get(key)
        if pkt is None:
            pkt = p.encode_instruction(sid, instruction, params)
            if instruction == p.READ and len(self._packets) < 4096:
                self._packets[key] = pkt
        fd = port.ser.fd
        try:
            if self._parser.pending or in_waiting(fd):
                self._skipped += self._parser.clear() + self._discard_input(fd)
            port.last_tx_time = self.clock()
            t0 = time.perf_counter()
            write_all(fd, pkt)
            if not expect_reply:
                return b'', COMM_SUCCESS, 0
            deadline = t0 + ((n_reply + 6) * BITS_TIMES_1000 / self.baud_rate + 2.0 * port.latency_timer_ms
                             + port.margin_ms) * 1e-3
            data, result, err = self._await_reply(fd, sid, n_reply, deadline)
        except (serial.SerialException, OSError, ValueError, TypeError) as exc:
            self._parser.clear()
            self.port_ok = False
            raise PortLostError(f'{self.device}: {exc}') from None
        if result == COMM_SUCCESS:
            # the adapter is a FIFO: every reply sent before this one has come or never will
            if self._unanswered:
                self._unanswered.clear()
        elif result == COMM_RX_TIMEOUT:
            self._unanswered.setdefault(sid, set()).add(n_reply)
        return data, result, err

    def _await_reply(self, fd: int, sid: int, n_reply: int, deadline: float) -> tuple[bytes, int, int]:
        chunk = b''
        while True:
            for pk in self._parser.feed(chunk):
                if pk.servo_id == sid and pk.length == n_reply + 2:
                    if not pk.checksum_ok:
                        self._skipped += pk.length + 4 + self._parser.clear()
                        return b'', COMM_RX_CORRUPT, 0
                    self.last_ok_t = self.clock()
                    return pk.params, COMM_SUCCESS, pk.code
                self._skipped += pk.length + 4          # answers something else (stale, foreign): skip it
            left = deadline - time.perf_counter()
            if left <= 0:
                return b'', COMM_RX_TIMEOUT, 0
            chunk = b''
            r, _, _ = select.select((fd,), (), (), left)
            if r:
                chunk = os.read(fd, 4096)
                if not chunk:
                    raise OSError('device reports readiness to read but returned no data (device disconnected?)')

    @staticmethod
    def _discard_input(fd: int) -> int:
        """Throw away whatever the port has buffered; returns how many bytes."""
        n = 0
        while True:
            r, _, _ = select.select((fd,), (), (), 0)
            if not r:
                return n
            chunk = os.read(fd, 4096)
            if not chunk:
                raise OSError('device disconnected')
            n += len(chunk)

    # ------------------------------------------------------------------ registers, with attempts
    def read(self, sid: int, address: int, n: int, attempts: int) -> ReadResult:
        """Read ``n`` bytes at ``address`` in up to ``attempts`` tries.

        Protocol 1.0 has no sequence numbers: what tells replies apart is their LENGTH. Each
        attempt asks for the fewest bytes, ``n`` or more, that no unanswered request to this servo
        asked for (:meth:`reply_length`), from an address moved down if the table ends: a reply
        later than its attempt, or than all of them, can never be taken for the answer to a later
        read of the same servo."""
        out = ReadResult()
        for _ in range(attempts):
            n_k = self.reply_length(sid, n)
            a_k = min(address, p.TABLE_SIZE - n_k)
            data, result, err = self.transact(sid, p.READ, [a_k, n_k], n_k)
            if result == COMM_SUCCESS:
                stamp = self.port.last_tx_time
                off = address - a_k
                out.data, out.stamp, out.t_com_s, out.error_bits = data[off:off + n], stamp, self.last_ok_t - stamp, err
                return out
            out.failures.append('no reply (timeout)' if result == COMM_RX_TIMEOUT else 'corrupt reply')
        return out

    def reply_length(self, sid: int, n: int) -> int:
        """The data length a READ of ``n`` bytes from servo ``sid`` asks for: ``n`` while every
        request to the servo was answered, else the smallest length from ``n`` up that no
        unanswered request to the servo asked for. When the table has no such length left (a
        servo silent for dozens of reads with no other servo answering in between), its
        unanswered requests are forgotten: ``n``."""
        busy = self._unanswered.get(sid)
        if not busy:
            return n
        n_k = n
        while n_k in busy:
            n_k += 1
        if n_k > p.TABLE_SIZE:
            busy.clear()
            return n
        return n_k

    def write(self, sid: int, address: int, data: list[int], attempts: int, who: str) -> None:
        """Write and wait for the servo's confirmation; BusError (naming ``who``) after ``attempts``
        tries or when the servo refuses the write. Alarm and voltage bits do not refuse it."""
        last = ''
        for _ in range(attempts):
            _d, result, err = self.transact(sid, p.WRITE, [address, *data], 0)
            if result == COMM_SUCCESS and err & p.ERR_CHECKSUM:
                last = 'the servo received a corrupt instruction (checksum error)'
                continue
            if result == COMM_SUCCESS:
                if err & ~ALARM_BITS & ~p.ERR_INPUT_VOLTAGE:
                    raise BusError(f'{who}: write of {data} at address {address} refused: {p.describe_error(err)}')
                return
            last = result_text(result)
        raise BusError(f'{who}: write at address {address} failed after {attempts} attempts: {last}')

    def send(self, sid: int, instruction: int, params: list[int]) -> float:
        """An instruction no servo answers (broadcast, or a write at status return level < 2);
        returns the time it was written."""
        self.transact(sid, instruction, params, 0, expect_reply=False)
        return self.port.last_tx_time
