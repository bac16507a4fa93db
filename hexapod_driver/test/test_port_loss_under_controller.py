"""The port vanishing while a controller in the driver's process owns the bus (the composed robot),
and while torque is to be turned off: the driver core and its LocalDriverBus against the emulated
bus, on a simulated clock."""
import pytest

from hexapod_driver.bus import DynamixelBus, EventKind
from hexapod_driver.config import DriverConfig
from hexapod_driver.local_bus import LocalDriverBus
from hexapod_model.bus import BusError

BASE = dict(timeout_margin_ms=25.0, read_retries=1, missing_after_failures=2, reprobe_period_s=0.05,
            reconnect_period_s=0.2, diagnostics_period_s=1e6, command_timeout_s=0.0)


class CostlyClock:
    """Simulated time that moves 1 ms at every look (and by every sleep), so a loop that only
    watches the clock still reaches its deadline; at ``replug_at`` the adapter comes back."""

    def __init__(self, emu, t0: float = 1000.0):
        self.t, self.emu, self.replug_at = t0, emu, None

    def _tick(self, dt: float) -> float:
        self.t += dt
        if self.replug_at is not None and self.t >= self.replug_at:
            self.replug_at = None
            self.emu.reconnect()
        return self.t

    def __call__(self) -> float:
        return self._tick(1e-3)

    def sleep(self, dt: float) -> None:
        self._tick(max(dt, 0.0))


def test_controller_read_and_write_survive_a_brief_port_loss(robot, emu):
    clock = CostlyClock(emu)
    core = DynamixelBus(robot, DriverConfig(device=emu.port, **BASE), clock=clock, sleep=clock.sleep)
    core.start()
    events, reads, writes = [], [], []
    local = LocalDriverBus(core, on_read=lambda *a: reads.append(a), on_write=lambda *a: writes.append(a),
                           on_step=lambda res: events.extend(res.events), read_timeout_s=2.0)
    try:
        emu.disconnect()
        clock.replug_at = clock.t + 0.6           # back well within the controller's read timeout
        theta, _stamp = local.read_position('leg1_femur')
        assert reads and reads[-1][0] == 'leg1_femur'
        kinds = [e.kind for e in events]
        assert kinds.count(EventKind.PORT_LOST) == 1, kinds            # said once, not per retry
        assert EventKind.RECONNECTED in kinds, kinds
        # a write while the adapter is away (a sync write has no reply: it may go out unnoticed),
        # then the read after it finds the loss, and waits for the port as well
        emu.disconnect()
        clock.replug_at = clock.t + 0.6
        local.sync_write({'leg1_femur': theta})
        assert writes
        local.read_position('leg2_femur')
        assert reads[-1][0] == 'leg2_femur'
        assert [e.kind for e in events].count(EventKind.PORT_LOST) == 2
    finally:
        core.shutdown()


def test_controller_read_fails_when_the_port_stays_away(robot, emu):
    clock = CostlyClock(emu)
    core = DynamixelBus(robot, DriverConfig(device=emu.port, **BASE), clock=clock, sleep=clock.sleep)
    core.start()
    events = []
    local = LocalDriverBus(core, on_read=lambda *a: None, on_write=lambda *a: None,
                           on_step=lambda res: events.extend(res.events), read_timeout_s=1.0)
    try:
        emu.disconnect()
        with pytest.raises(BusError):
            local.read_position('leg1_femur')
        kinds = {e.kind for e in events}
        assert {EventKind.PORT_LOST, EventKind.RECONNECT_FAILED} <= kinds, kinds
    finally:
        emu.reconnect()
        ok, text = core.shutdown()
        assert ok, text


def test_torque_off_reopens_a_port_that_came_back(robot, emu):
    core = DynamixelBus(robot, DriverConfig(device=emu.port, **BASE))
    core.start()
    assert all(s.get('torque_enable') == 1 for s in emu.servos)
    emu.disconnect()
    with pytest.raises(BusError):
        core.read_position('leg1_femur')        # the driver now knows the port is lost
    assert not core.port_ok
    emu.reconnect()                             # the adapter is back before the driver exits
    ok, text = core.shutdown()
    assert ok, text
    assert text == 'torque off on all servos (read back)'
    assert all(s.get('torque_enable') == 0 for s in emu.servos)


def test_torque_off_says_unknown_when_the_port_stays_away(robot, emu):
    core = DynamixelBus(robot, DriverConfig(device=emu.port, **{**BASE, 'reconnect_period_s': 0.05}))
    core.start()
    emu.disconnect()
    ok, text = core.shutdown()
    assert not ok
    assert 'torque state unknown' in text
