"""An AX-12A bus on a pseudo-terminal: 18 emulated servos speaking Protocol 1.0 byte for byte.

The driver (or any Dynamixel tool) opens the pty's slave path exactly as it would open
``/dev/ttyUSB0`` and cannot tell the difference: instruction packets are parsed with checksum
checks, status packets carry the error byte, the return delay time (address 5, x 2 us) is
honoured, the control table has EEPROM (persists over :meth:`BusEmulator.power_cycle`) and RAM
(reset at power-up) semantics, range/angle-limit/lock checks, the status return level, REG_WRITE +
ACTION, SYNC_WRITE and the alarm shutdown (an alarm in ``alarm_shutdown`` zeroes the torque limit;
writing a non-zero torque limit recovers once the cause is gone).

What the horns do is a *backend*:

* :class:`IdealServoBackend`: a servo that follows its goal at the moving speed (register 32;
  0 = the no-load speed) on the 1 kHz firmware grid, limp when torque is off;
* :class:`ServoBusBackend`: an adapter over any :class:`hexapod_model.bus.ServoBus` (the MuJoCo
  sim ``hexapod_sim.physics.plant.HexapodSim``): goal writes become ``sync_write`` and position reads
  ``wait_until`` + ``read_position`` on that bus, with the robot description's mounting
  (direction, offset) between DH angle and raw tick.

Fault injection (:class:`Faults`): dropped replies, corrupt checksums, late (stale) replies ahead of
the real one, every reply held back by an adapter latency (:meth:`Faults.set_reply_latency`, the
FTDI latency timer), a reply held back longer still, with the replies behind it
(:meth:`Faults.hold_replies`, a USB stall), a servo that disappears,
overheating (temperature above the limit at address 11), overload, input voltage, and the whole
port vanishing (:meth:`BusEmulator.disconnect`) and coming back (:meth:`BusEmulator.reconnect`,
behind a stable symlink like a udev name). A servo whose baud rate register (address 4) does not
match the rate the host opened the port at (the pty's termios speed) does not answer, and the
status return level (address 16) is honoured as the e-manual defines it: 0 = status packets only
for PING, 1 = only for PING and READ, 2 = for every instruction (never for broadcasts).

The log (:attr:`BusEmulator.log`) keeps every instruction as received (``rx``), the bytes sent
back (``tx``, as corrupted or prefixed) and, without a reply, why (``note``).

Timing convention: emulator time is seconds since :meth:`BusEmulator.start` on its clock; the
firmware ticks at integer milliseconds of it; a goal takes effect at the first tick at or after
the instruction's arrival; a READ samples the position at the instruction's arrival (the start
of the transaction). With ``wire_time=True`` the reply is additionally held back by the wire time
of both packets at the configured baud rate (10 bits per byte), so round trips look like a real
1 Mbps bus; with ``wire_time=False`` only the return delay is applied.

The package by job: :mod:`.control_table` (one servo's registers and error conditions),
:mod:`.backends` (what moves the horns, and the plug-in group for more), :mod:`.faults` (fault
injection), :mod:`.pty_server` (:class:`BusEmulator`: the pseudo-terminal, packet handling,
timing), :mod:`.cli` (``bus_emulator``).
"""
from hexapod_driver.emulator.backends import (
                       BACKEND_GROUP,
                       IdealServoBackend,
                       ServoBackend,
                       ServoBusBackend,
                       backend_plugins,
                       firmware_tick_at_or_after,
)
from hexapod_driver.emulator.control_table import EmulatedServo, EmulatorError
from hexapod_driver.emulator.faults import Faults
from hexapod_driver.emulator.pty_server import BusEmulator, LogEntry

__all__ = ['BACKEND_GROUP', 'BusEmulator', 'EmulatedServo', 'EmulatorError', 'Faults', 'IdealServoBackend',
           'LogEntry', 'ServoBackend', 'ServoBusBackend', 'backend_plugins', 'firmware_tick_at_or_after']
