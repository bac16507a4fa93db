"""LocalDriverBus (the driver's bus in the controller's thread): its idle loop never makes the
controller's next step late. On a simulated clock: no wall time is involved."""
import math

from hexapod_driver.bus import StepResult
from hexapod_driver.local_bus import LocalDriverBus


class FakeCore:
    """The parts of DynamixelBus the local bus uses: a read takes ``t_read`` and the next read may
    start ``read_period`` after the last one; ``step`` waits for that slot, as the driver's does,
    and every third step also reads a diagnostics register (a second transaction)."""

    def __init__(self, t_com=1e-3, t_read=0.25e-3, read_period=1e-3):
        self.t, self.t_com_s, self.t_read, self.read_period = 0.0, t_com, t_read, read_period
        self._next = -math.inf
        self.step_ends = []

    def now(self):
        return self.t

    @property
    def next_read_t(self):
        return self._next

    def _read(self):
        self.t += self.t_read
        self._next = self.t - self.t_read + self.read_period
        return self.t

    def read_position(self, joint):
        return 0.0, self._read() - self.t_read

    def sync_write(self, goals):
        return self.t

    def step(self):
        self.t = max(self.t, self._next)
        self._read()
        if len(self.step_ends) % 3 == 2:        # a diagnostics round is due
            self.t += self.t_read
        self.step_ends.append(self.t)
        return StepResult()

    def wait_until(self, t):
        self.t = max(self.t, t)


def test_idle_reads_fill_the_gap_but_never_run_past_the_next_control_step():
    core = FakeCore()
    bus = LocalDriverBus(core, on_read=lambda *a: None, on_write=lambda *a: None, on_step=lambda r: None)
    t_con = 3e-3
    for k in range(1, 200):                      # Algorithm 1: write, read three femurs, wait for t_con
        bus.sync_write({})
        for j in ('leg1_femur', 'leg3_femur', 'leg5_femur'):
            bus.read_position(j)
        bus.wait_until(k * t_con)
        assert core.now() == k * t_con           # the next step starts on time
    assert core.step_ends and max(core.step_ends) <= 199 * t_con
    assert all(e <= math.ceil(e / t_con - 1e-9) * t_con + 1e-12 for e in core.step_ends)
    assert len(core.step_ends) >= 150            # the bus is not left idle: about one read per gap


def test_a_slow_bus_skips_the_idle_read_rather_than_delay_the_controller():
    core = FakeCore(t_read=0.9e-3)               # reads as slow as the description's T_com
    bus = LocalDriverBus(core, on_read=lambda *a: None, on_write=lambda *a: None, on_step=lambda r: None)
    for k in range(1, 50):
        for j in ('leg1_femur', 'leg3_femur', 'leg5_femur'):
            bus.read_position(j)
        bus.wait_until(k * 3e-3)
        assert core.now() == k * 3e-3


def test_every_read_is_observed_the_controllers_and_the_loops_own():
    """What the driver publishes on /joint_states, handed to an observer in the reading thread: the
    controller's reads and the loop's background reads, each once, in order."""
    from hexapod_driver.bus.state import Sample
    core = FakeCore()

    def step():
        FakeCore.step(core)
        return StepResult(samples=[Sample('leg2_tibia', 0.5, 512, core.t - core.t_read, core.t_read, 0)])

    core.step = step
    published, seen = [], []
    bus = LocalDriverBus(core, on_read=lambda j, th, t: published.append((j, th, t)), on_write=lambda *a: None,
                         on_step=lambda r: published.extend((s.joint, s.theta_rad, s.stamp) for s in r.samples))
    bus.observe_reads(lambda names, pos, t: seen.extend(zip(names, pos, [t] * len(names))))
    bus.read_position('leg1_femur')
    bus.wait_until(5e-3)
    bus.read_position('leg3_femur')
    assert [j for j, _, _ in seen] == ['leg1_femur'] + ['leg2_tibia'] * 4 + ['leg3_femur']
    assert seen == published
