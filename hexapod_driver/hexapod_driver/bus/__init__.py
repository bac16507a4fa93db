"""The driver core: one AX-12A bus (Protocol 1.0), without any ROS import, in layers.

=================  ===========================================================================
``transport``      the serial port, reconnection, framing (:class:`~hexapod_driver.protocol.PacketParser`,
                   shared with the bus emulator), a register read/write with N attempts
``servo_setup``    start-up verification (PING, model number, reply latency) and configuration
                   (EEPROM only when it differs, the servo law, goal = present position, torque)
``policy``         per servo: failed reads, missing servos, error bits, the fault policy, diagnostics
``commands``       goal validation, pending goals, the hold on a silent command stream, the read schedule
``loop``           the bus loop, one step at a time: reopen, write, hold, read, diagnostics, clock watch
``events``         what the driver says, as typed records (:class:`Event`: kind and fields)
``state``          what the layers pass between them: a read (:class:`Sample`), a servo's :class:`ServoState`
``host``           what the layers that work on the bus holding them use of it (``BusHost``)
``core``           :class:`DynamixelBus`, built from the above; the ``ServoBus`` protocol
=================  ===========================================================================

The layers import one way: ``state``, ``events``, ``transport``, ``host`` and ``commands`` at the bottom, then
``servo_setup``, ``policy``, ``loop`` and ``core`` on top. A layer that works on the bus holding it
declares what it uses of that bus (``SetupHost``, ``PolicyHost``, ``LoopHost``: ``BusHost`` and more, which
:class:`DynamixelBus` implements) instead of importing :mod:`core`.
"""
from hexapod_driver.bus.commands import CommandError, Validated
from hexapod_driver.bus.core import DynamixelBus
from hexapod_driver.bus.events import Event, EventKind, EventLog
from hexapod_driver.bus.loop import StepResult
from hexapod_driver.bus.servo_setup import ServoVerificationError
from hexapod_driver.bus.state import Sample, ServoState
from hexapod_driver.bus.transport import PortLostError, ReadResult, Transport

__all__ = ['CommandError', 'DynamixelBus', 'Event', 'EventKind', 'EventLog', 'PortLostError', 'ReadResult',
           'Sample', 'ServoState', 'ServoVerificationError', 'StepResult', 'Transport', 'Validated']
