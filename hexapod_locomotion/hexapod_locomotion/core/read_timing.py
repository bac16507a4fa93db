"""Whether a walk's reads still fit Algorithm 1's timing (pure Python; the locomotion node reports it).

Algorithm 1 (and the model behind Eq. 17) assumes that the goals written at step ``k`` take effect
when they are written, and that the step's femur reads follow, one leg after the other, at
``k t_con + l T_com``. Two things break that, and :class:`ReadTiming` counts both:

* **Late reads.** Over DDS the controller's time is the stamp of the newest read it has received
  (:mod:`hexapod_locomotion.nodes.ros_bus`). A read taken ``age`` seconds after the bus master
  published it (a backlog in the subscriber: a loaded computer) means the controller acts that
  far behind the master: its goals reach the servos ``age`` later than the model has them, and the
  measured error runs ahead of the prediction by the goal's motion over that time. With the femur
  goal moving ``r`` ticks per second, the Eq. 17 margin of ``epsilon`` ticks is used up after
  ``epsilon / r`` seconds: a read older than that (:meth:`ReadTiming.tolerance_s`) can stop a free
  leg in the air. The age needs the bus's publication time of each read (the DDS source
  timestamp, on the publisher's system clock); a bus in this process has none and reads no age,
  and in lock-step the bus master waits for the goals, so the node passes none.
* **Reads out of order.** A read sampled before the read taken just before it in the same
  swing-down: the model's read instants no longer follow the bus, and ``analyse`` can replay
  such a walk only from the reads the controller recorded on ``/ground_detection``.

Reads out of order do not change the live decisions (each read is placed on the model's time axis
by its own stamp), so they are one line per walk; late reads are one line in each swing-down that
has them. :meth:`ReadTiming.on_read` returns that line (naming what and by how much);
:meth:`ReadTiming.status` is the ``/diagnostics`` status with the counts.
"""
from __future__ import annotations

import math

from hexapod_model import diagnostics


class ReadTiming:
    """Counts of late and out-of-order reads over a walk; one warning per swing-down and kind."""

    def __init__(self, node: str = 'locomotion_node'):
        self.node = node
        self.reads = 0
        self.late_reads = 0
        self.out_of_order_reads = 0
        self.max_age_s = 0.0
        self.max_order_s = 0.0
        self.phases = 0
        self.phases_late = 0
        self.phases_out_of_order = 0
        self._tolerance_s = math.inf
        self._margin = ''
        self._last_stamp: float | None = None
        self._warned: set[str] = set()
        self._order_said = False

    @staticmethod
    def tolerance_s(phase) -> tuple[float, str]:
        """How old a read of ``phase`` (a :class:`~hexapod_locomotion.core.detector.SwingDownPhase`) may be
        before its goal's delay uses up the Eq. 17 margin, and the margin's arithmetic as text."""
        eps = phase.config.epsilon_tick
        rate = max(phase.femur_step_tick(leg) for leg in phase.legs) / phase.t_con_s      # ticks per second
        if rate <= 0:
            return math.inf, f'the femur goals stand still (Eq. 17 margin {eps:g} ticks)'
        return eps / rate, f'Eq. 17 margin {eps:g} ticks at the femur goal\'s {rate * 1e-3:.2f} ticks/ms'

    def start_phase(self, phase) -> None:
        """A swing-down begins (its goals' speed sets the tolerance)."""
        self.phases += 1
        self._tolerance_s, self._margin = self.tolerance_s(phase)
        self._last_stamp = None
        self._warned = set()

    def on_read(self, leg: int, step: int, stamp_s: float, age_s: float | None) -> str | None:
        """One read the controller decided on: ``stamp_s`` its sample time (bus time), ``age_s`` how
        long after the bus master published it the controller took it (None: unknown). Returns a
        warning line the first time this swing-down breaks a rule, else None."""
        self.reads += 1
        line = None
        if age_s is not None and math.isfinite(age_s):
            self.max_age_s = max(self.max_age_s, age_s)
            if age_s > self._tolerance_s:
                self.late_reads += 1
                if 'late' not in self._warned:
                    self._warned.add('late')
                    self.phases_late += 1
                    line = (f'read timing no longer valid for Algorithm 1: leg {leg} step {step} read taken '
                            f'{age_s * 1e3:.0f} ms after the bus master published it, the walk allows '
                            f'{self._tolerance_s * 1e3:.0f} ms ({self._margin}); the goals reach the servos that '
                            'much later than the model has them, so legs may stop in the air (a loaded computer '
                            'or DDS backlog; the composed robot has none)')
        last = self._last_stamp
        if last is not None and stamp_s < last:
            behind = last - stamp_s
            self.out_of_order_reads += 1
            self.max_order_s = max(self.max_order_s, behind)
            if 'order' not in self._warned:
                self._warned.add('order')
                self.phases_out_of_order += 1
            if not self._order_said:             # harmless to the decisions: one line per walk
                self._order_said = True
                text = (f'reads out of Algorithm 1 order: leg {leg} step {step} read sampled {behind * 1e3:.1f} ms '
                        'before the read taken just before it (the bus master reads on its own schedule; the '
                        'decisions place each read by its stamp, and analyse replays the reads /ground_detection '
                        'names; counted in /diagnostics, not said again)')
                line = text if line is None else f'{line}; {text}'
        self._last_stamp = stamp_s if last is None else max(last, stamp_s)
        return line

    def status(self) -> diagnostics.Status:
        """``<node>: read timing`` for /diagnostics: WARN once a read was late or out of order."""
        problems = []
        if self.late_reads:
            problems.append(f'{self.late_reads} late reads in {self.phases_late} of {self.phases} swing-downs '
                            f'(oldest {self.max_age_s * 1e3:.0f} ms)')
        if self.out_of_order_reads:
            problems.append(f'{self.out_of_order_reads} reads out of Algorithm 1 order in {self.phases_out_of_order} '
                            f'of {self.phases} swing-downs (by up to {self.max_order_s * 1e3:.1f} ms)')
        level = diagnostics.WARN if problems else diagnostics.OK
        message = '; '.join(problems) or f'OK: {self.reads} reads in {self.phases} swing-downs on time and in order'
        tol = self._tolerance_s
        values = (('reads', str(self.reads)), ('late_reads', str(self.late_reads)),
                  ('out_of_order_reads', str(self.out_of_order_reads)), ('swing_downs', str(self.phases)),
                  ('swing_downs_with_late_reads', str(self.phases_late)),
                  ('swing_downs_with_reads_out_of_order', str(self.phases_out_of_order)),
                  ('max_read_age_ms', f'{self.max_age_s * 1e3:.1f}'),
                  ('max_out_of_order_ms', f'{self.max_order_s * 1e3:.1f}'),
                  ('read_age_tolerance_ms', f'{tol * 1e3:.1f}' if math.isfinite(tol) else 'inf'))
        return diagnostics.Status(level, f'{self.node}: read timing', message, 'algorithm 1', values)
