"""Whether a walk's reads fit Algorithm 1's timing (read_timing), and which reads ``analyse`` replays
(the ones the controller took, in its order)."""
import pytest

from hexapod_locomotion.core.detector import DetectorConfig, SwingDownPhase
from hexapod_locomotion.core.read_timing import ReadTiming
from hexapod_locomotion.trials.analyse import controller_reads
from hexapod_model import diagnostics
from hexapod_model.description import load_robot

RAISED = [0.9, -0.9]
FIN = [0.05, -0.75]


@pytest.fixture(scope='module')
def phase():
    return SwingDownPhase(load_robot(), (1, 6, 3), [0.0] * 3, [RAISED] * 3, [FIN] * 3, 1.0, 0.001,
                          DetectorConfig(detector='adaptive', epsilon_tick=3.0))


def test_the_tolerance_is_the_eq17_margin_over_the_femur_goal_speed(phase):
    tol, text = ReadTiming.tolerance_s(phase)
    rate = phase.femur_step_tick(1) / phase.t_con_s            # ticks per second, the same for the three legs
    assert tol == pytest.approx(3.0 / rate)
    assert 0.005 < tol < 0.1 and 'Eq. 17 margin 3 ticks' in text


def test_a_late_read_is_one_line_per_swing_down_and_counted(phase):
    t = ReadTiming()
    tol, _ = ReadTiming.tolerance_s(phase)
    t.start_phase(phase)
    assert t.on_read(1, 0, 0.010, 0.002) is None
    line = t.on_read(6, 0, 0.011, tol + 0.150)
    assert line is not None and 'leg 6 step 0' in line
    assert f'{(tol + 0.150) * 1e3:.0f} ms after the bus master published it' in line
    assert f'allows {tol * 1e3:.0f} ms' in line
    assert t.on_read(3, 0, 0.012, tol + 0.2) is None            # the same swing-down: counted, not said again
    t.start_phase(phase)
    assert t.on_read(1, 0, 0.020, tol * 2) is not None         # the next swing-down says it again
    st = t.status()
    assert st.level == diagnostics.WARN and st.name == 'locomotion_node: read timing'
    values = dict(st.values)
    assert values['late_reads'] == '3' and values['swing_downs_with_late_reads'] == '2'
    assert values['max_read_age_ms'] == f'{(tol + 0.2) * 1e3:.1f}'


def test_reads_out_of_order_are_said_once_per_walk_and_counted(phase):
    t = ReadTiming()
    t.start_phase(phase)
    assert t.on_read(1, 0, 0.010, None) is None
    line = t.on_read(6, 0, 0.008, None)
    assert line is not None and 'out of Algorithm 1 order' in line and '2.0 ms before' in line
    t.start_phase(phase)
    assert t.on_read(1, 0, 0.030, None) is None
    assert t.on_read(6, 0, 0.029, None) is None                 # said once per walk, still counted
    values = dict(t.status().values)
    assert values['out_of_order_reads'] == '2' and values['swing_downs_with_reads_out_of_order'] == '2'
    assert values['late_reads'] == '0'                          # no age known (a bus in this process)


def test_on_time_and_in_order_is_ok(phase):
    t = ReadTiming()
    t.start_phase(phase)
    for k in range(5):
        for slot, leg in enumerate(phase.legs):
            assert t.on_read(leg, k, 0.003 * k + 0.001 * slot, 0.001) is None
    assert t.status().level == diagnostics.OK


def test_analyse_replays_the_reads_the_controller_took_in_its_order():
    """Over DDS the controller takes the newest read of each femur: the j-th read of each leg belongs
    to step j whatever the stamps' order across legs, and the bus's other reads are not replayed."""
    legs = (2, 5, 4)
    ns = lambda ms: int(ms * 1e6)                                        # noqa: E731
    taken = {2: [ns(38), ns(41)], 5: [ns(39), ns(42)], 4: [ns(37), ns(43)]}     # leg 4 sampled first at step 0
    femur_at = {(leg, t): (0.1 * leg, t * 1e-9) for leg, ts in taken.items() for t in ts}
    femur_at[(2, ns(40))] = (9.9, 0.040)                                # a bus read the controller never took
    reads = controller_reads(taken, femur_at, legs)
    assert [(leg, round(t * 1e3, 3)) for leg, _, t in reads] == [(2, 38), (5, 39), (4, 37), (2, 41), (5, 42), (4, 43)]
    assert all(theta == pytest.approx(0.1 * leg) for leg, theta, _ in reads)
    lost = {**taken, 4: [ns(37)]}                             # a /ground_detection message lost
    assert controller_reads(lost, femur_at, legs) is None
    assert controller_reads(taken, {k: v for k, v in femur_at.items() if k != (5, ns(42))}, legs) is None
