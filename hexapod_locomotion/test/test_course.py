"""Course correction (hexapod_locomotion.core.course) on poses whose errors are known."""
import math
import re
from pathlib import Path

import pytest

import hexapod_locomotion
from hexapod_locomotion.core.course import CourseConfig, CourseKeeper, placed_turn_share
from hexapod_locomotion.core.gait import load_gaits
from hexapod_locomotion.core.locomotion_params import LocomotionError, VelocityCommand

CYCLE = 2.0


def test_on_course_the_command_is_unchanged():
    k = CourseKeeper()
    cmd = VelocityCommand(0.05, 0.0, 0.0)
    assert k.command(0.0, cmd, (0.0, 0.0), 0.0, CYCLE) == cmd
    assert k.command(1.0, cmd, (0.05, 0.0), 0.0, CYCLE) == cmd


def test_heading_error_becomes_yaw_rate():
    """Start at yaw 0; the body has turned to -0.1 rad a second later. The errors are means over the last
    cycle (2 s: both samples): heading -0.05 rad, half of it (gain 0.5) over the 2 s cycle is +0.0125 rad/s."""
    k = CourseKeeper(CourseConfig(heading_gain=0.5, lateral_gain=0.0))
    cmd = VelocityCommand(0.05, 0.0, 0.0)
    k.command(0.0, cmd, (0.0, 0.0), 0.0, CYCLE)
    out = k.command(1.0, cmd, (0.05, 0.0), -0.1, CYCLE)
    assert out.wz == pytest.approx(0.0125)
    assert (out.vx, out.vy) == pytest.approx((0.05, 0.0))


def test_left_of_the_line_walks_right():
    """0 then 2 cm left of the start line (mean over the cycle 1 cm), heading straight: -0.5 * 0.01 / 2 s =
    -2.5 mm/s sideways (body frame y)."""
    k = CourseKeeper(CourseConfig(heading_gain=0.0, lateral_gain=0.5))
    cmd = VelocityCommand(0.05, 0.0, 0.0)
    k.command(0.0, cmd, (0.0, 0.0), 0.0, CYCLE)
    out = k.command(1.0, cmd, (0.05, 0.02), 0.0, CYCLE)
    assert out.vy == pytest.approx(-0.0025)
    assert out.vx == pytest.approx(0.05)
    # the same error with the body turned by 90 degrees: the correction is -y in odom = +x in the body
    k = CourseKeeper(CourseConfig(heading_gain=0.0, lateral_gain=0.5, max_heading_error_rad=4.0))
    k.command(0.0, cmd, (0.0, 0.0), 0.0, CYCLE)
    out = k.command(1.0, cmd, (0.05, 0.02), -math.pi / 2, CYCLE)
    assert out.vx == pytest.approx(0.05 + 0.0025)
    assert out.vy == pytest.approx(0.0, abs=1e-12)


def test_a_command_faster_than_the_gait_is_slowed_before_the_sideways_correction():
    """The controller scales a step longer than its stride down, the sideways part with it: asked 0.05 m/s of
    a gait that walks 0.02, a correction of -2.5 mm/s sideways would move it 1 mm/s. The keeper caps the
    forward command at the gait's speed first, so the step keeps the sideways share asked for."""
    k = CourseKeeper(CourseConfig(heading_gain=0.0, lateral_gain=0.5))
    cmd = VelocityCommand(0.05, 0.0, 0.0)
    k.command(0.0, cmd, (0.0, 0.0), 0.0, CYCLE, 0.02)
    out = k.command(1.0, cmd, (0.02, 0.02), 0.0, CYCLE, 0.02)
    assert (out.vx, out.vy) == pytest.approx((0.02, -0.0025))
    assert k.command(2.0, VelocityCommand(0.01, 0.0, 0.0), (0.02, 0.0), 0.0, CYCLE, 0.02).vx == pytest.approx(0.01)


def test_turning_in_place_follows_the_integrated_rate():
    """Commanded 0.1 rad/s for 4 s: the reference is at 0.4 rad; a robot at 0.3 rad gets 0.1 + 0.5 * 0.1 / 2."""
    k = CourseKeeper(CourseConfig(heading_gain=0.5))
    cmd = VelocityCommand(0.0, 0.0, 0.1)
    k.command(0.0, cmd, (0.0, 0.0), 0.0, CYCLE)
    k.command(2.0, cmd, (0.0, 0.0), 0.2, CYCLE)
    out = k.command(4.0, cmd, (0.0, 0.0), 0.3, CYCLE)
    assert out.wz == pytest.approx(0.1 + 0.025)
    assert (out.vx, out.vy) == (0.0, 0.0)


def test_the_sway_within_a_cycle_is_not_corrected():
    """The heading swings +-0.07 rad around the reference within each 2 s cycle: the mean error is 0."""
    k = CourseKeeper()
    cmd = VelocityCommand(0.05, 0.0, 0.0)
    outs = [k.command(0.5 * i, cmd, (0.01 * i, 0.0), 0.07 * round(math.sin(i * math.pi / 2)), CYCLE) for i in range(12)]
    assert outs[-1].wz == pytest.approx(0.0, abs=1e-12)


def test_a_new_command_starts_a_new_reference():
    k = CourseKeeper(CourseConfig(heading_gain=0.5))
    k.command(0.0, VelocityCommand(0.05, 0.0, 0.0), (0.0, 0.0), 0.0, CYCLE)
    out = k.command(1.0, VelocityCommand(0.04, 0.0, 0.0), (0.05, 0.03), 0.2, CYCLE)
    assert out == VelocityCommand(0.04, 0.0, 0.0)


def test_the_reference_is_not_wound_up():
    k = CourseKeeper(CourseConfig(heading_gain=0.5, max_heading_error_rad=0.3))
    cmd = VelocityCommand(0.0, 0.0, 1.0)
    k.command(0.0, cmd, (0.0, 0.0), 0.0, CYCLE)
    out = k.command(2.0, cmd, (0.0, 0.0), 0.0, CYCLE)     # asked for 2 rad, turned none
    assert out.wz == pytest.approx(1.0 + 0.5 * 0.3 / CYCLE)


def test_bad_gain_is_named():
    with pytest.raises(LocomotionError, match='heading_gain'):
        CourseConfig(heading_gain=math.nan)


def test_walking_straight_the_reference_holds_however_far_the_body_yawed():
    """A leg stalled on a block yawed the body by 0.4 rad (more than max_heading_error_rad): the reference
    stays at the start heading, so once the body is back there nothing more is corrected."""
    k = CourseKeeper(CourseConfig(heading_gain=0.5, max_heading_error_rad=0.3, trend=0.0))
    cmd = VelocityCommand(0.05, 0.0, 0.0)
    k.command(0.0, cmd, (0.0, 0.0), 0.0, CYCLE)
    out = k.command(2.0, cmd, (0.1, 0.0), -0.4, CYCLE)
    assert k.yaw_ref == 0.0
    assert out.wz == pytest.approx(0.5 * 0.3 / CYCLE)          # the correction asked for is limited
    k.command(4.0, cmd, (0.2, 0.0), 0.0, CYCLE)
    out = k.command(6.0, cmd, (0.3, 0.0), 0.0, CYCLE)
    assert out.wz == pytest.approx(0.0, abs=1e-12)


def test_the_yaw_rate_is_divided_by_the_share_of_the_placed_turn():
    assert placed_turn_share(2) == pytest.approx(2 / 3)
    assert placed_turn_share(3) == pytest.approx(3 / 4)
    assert placed_turn_share(6) == pytest.approx(6 / 7)
    k = CourseKeeper(turn_share=0.75)
    cmd = VelocityCommand(0.0, 0.0, 0.1)
    assert k.command(0.0, cmd, (0.0, 0.0), 0.0, CYCLE).wz == pytest.approx(0.1 / 0.75)
    with pytest.raises(LocomotionError, match='turn_share'):
        CourseKeeper(turn_share=0.0)


@pytest.mark.parametrize('name', sorted(load_gaits()))
def test_the_keeper_of_each_gait_divides_by_its_own_turn_share(name):
    """Each gait of gaits.yaml: the keeper built for it turns in place at the commanded rate divided by
    n / (n + 1) of its groups (tripod 2/3, tetrapod 3/4, pentapod 6/7)."""
    gait = load_gaits()[name]
    n = len(gait.groups)
    k = CourseKeeper.for_gait(gait)
    assert k.turn_share == pytest.approx(n / (n + 1))
    assert k.config == CourseConfig()
    cmd = VelocityCommand(0.0, 0.0, 0.1)
    assert k.command(0.0, cmd, (0.0, 0.0), 0.0, CYCLE).wz == pytest.approx(0.1 * (n + 1) / n)
    tuned = CourseConfig(heading_gain=0.2)
    assert CourseKeeper.for_gait(gait, tuned).config is tuned


def test_every_walker_builds_its_keeper_from_the_gait():
    """locomotion_node and the trial runner walk with the same keeper for the same gait: no module but
    the course's own constructs CourseKeeper directly, and both walkers call CourseKeeper.for_gait and
    give it the gait's speed."""
    root = Path(hexapod_locomotion.__file__).parent
    direct = [f'{p.relative_to(root)}:{i}' for p in sorted(root.rglob('*.py')) if p.name != 'course.py'
              for i, line in enumerate(p.read_text().splitlines(), 1) if re.search(r'\bCourseKeeper\(', line)]
    assert direct == []
    for walker in ('nodes/locomotion_node.py', 'trials/trial_runner.py'):
        assert 'CourseKeeper.for_gait(' in (root / walker).read_text(), walker
        assert 'saturating_velocity(gait)[0]' in (root / walker).read_text(), walker     # the gait's speed


def test_the_heading_error_is_carried_on_by_its_trend():
    """The body yaws at -0.05 rad/s, sampled every second (cycle 2 s). At t = 4 s the last cycle's samples
    (t = 3, 4) average 0.175 rad of error at t = 3.5; the cycle before (t = 1, 2) 0.075 at t = 1.5: the
    error grows by 0.05 rad/s, so now it is 0.2 rad, and the yaw rate asked is 0.5 * 0.2 / 2 s (on the
    mean alone 0.5 * 0.175 / 2 s)."""
    k = CourseKeeper(CourseConfig(heading_gain=0.5, lateral_gain=0.0, trend=1.0))
    cmd = VelocityCommand(0.05, 0.0, 0.0)
    for t in range(4):
        k.command(float(t), cmd, (0.05 * t, 0.0), -0.05 * t, CYCLE)
    assert k.command(4.0, cmd, (0.2, 0.0), -0.2, CYCLE).wz == pytest.approx(0.5 * 0.2 / CYCLE)
    plain = CourseKeeper(CourseConfig(heading_gain=0.5, lateral_gain=0.0, trend=0.0))
    for t in range(4):
        plain.command(float(t), cmd, (0.05 * t, 0.0), -0.05 * t, CYCLE)
    assert plain.command(4.0, cmd, (0.2, 0.0), -0.2, CYCLE).wz == pytest.approx(0.5 * 0.175 / CYCLE)
