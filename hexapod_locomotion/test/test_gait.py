"""Gaits as data: support counts at every phase, phase offsets, validation."""
import math

import pytest

from hexapod_locomotion.core.gait import DEFAULT_STRIDE_M, DEFAULT_TURN_RAD, Gait, GaitError, get_gait, load_gaits


@pytest.mark.parametrize('name, down', [('tripod', 3), ('tetrapod', 4), ('pentapod', 5)])
def test_feet_down_at_every_tick(name, down):
    gait = get_gait(name)
    for tick in range(-12, 60):
        assert len(gait.stance_legs(tick)) == down
        assert set(gait.stance_legs(tick)) | set(gait.swing_legs(tick)) == {1, 2, 3, 4, 5, 6}
    assert gait.min_support == down


def test_tripod_alternates_the_paper_triangles():
    g = get_gait('tripod')
    assert set(g.swing_legs(0)) == {1, 6, 3} and set(g.swing_legs(1)) == {2, 5, 4}
    # each tripod is a triangle: front and rear on one side, middle on the other
    left = {1, 3, 5}
    for phase in (0, 1):
        sw = set(g.swing_legs(phase))
        assert len(sw & left) in (1, 2) and len(sw - left) in (1, 2)


def test_support_polygon_never_one_sided():
    left, right = {1, 3, 5}, {2, 4, 6}
    for name in ('tripod', 'tetrapod', 'pentapod'):
        g = get_gait(name)
        for phase in range(g.n_phases):
            st = set(g.stance_legs(phase))
            assert st & left and st & right, (name, phase)


def test_phase_offsets():
    off = get_gait('pentapod').phase_offsets()
    assert sorted(off.values()) == pytest.approx([0, 1 / 6, 2 / 6, 3 / 6, 4 / 6, 5 / 6])


def test_bad_gaits_are_named(tmp_path):
    with pytest.raises(GaitError, match='exactly once'):
        Gait('broken', ((1, 2, 3), (3, 4, 5)))
    with pytest.raises(GaitError, match="unknown gait 'hopping'"):
        get_gait('hopping')
    p = tmp_path / 'g.yaml'
    p.write_text('wobble:\n  groups: [[1, 2], [x]]\n')
    with pytest.raises(GaitError, match=f"^{p}: gait 'wobble'"):        # the file, then the gait
        load_gaits(p)
    p.write_text('wobble: [1, 2')
    with pytest.raises(GaitError, match=f'^{p}: not valid YAML: line 1, column 14: ') as err:
        load_gaits(p)
    assert '\n' not in str(err.value) and 'unicode string' not in str(err.value)
    p.write_text('wave:\n  groups: [[1], [2], [3], [4], [5], [6]]\n  max_stride_m: far\n')
    with pytest.raises(GaitError, match="gait 'wave': max_stride_m must be a number"):
        load_gaits(p)
    with pytest.raises(GaitError, match='finite positive'):
        Gait('wave', ((1,), (2,), (3,), (4,), (5,), (6,)), -0.1)


def test_a_gait_has_its_stride_and_the_parameter_replaces_it():
    from hexapod_locomotion.core.locomotion_params import LocomotionParams
    p = LocomotionParams()
    assert p.stride_m(get_gait('pentapod')) == get_gait('pentapod').max_stride_m == 0.12
    assert p.stride_m(get_gait('tripod')) == DEFAULT_STRIDE_M
    assert LocomotionParams(max_stride_m=0.05).stride_m(get_gait('pentapod')) == 0.05
    assert LocomotionParams(max_stride_m=0.10).stride_m(get_gait('tripod')) == 0.10


def test_a_gait_has_its_turn_and_the_parameter_replaces_it(tmp_path):
    """The pentapod's 5.9 s cycle turns up to 0.4 rad per cycle (0.25 capped its turn in place at
    0.036 rad/s); the others keep 0.25; the controller's parameter, when set, replaces both."""
    from hexapod_locomotion.core.locomotion_params import LocomotionParams
    p = LocomotionParams()
    assert p.turn_rad(get_gait('pentapod')) == 0.4
    assert p.turn_rad(get_gait('tripod')) == p.turn_rad(get_gait('tetrapod')) == DEFAULT_TURN_RAD == 0.25
    assert LocomotionParams(max_turn_rad=0.1).turn_rad(get_gait('pentapod')) == 0.1
    assert p.saturating_velocity(get_gait('pentapod'))[1] == pytest.approx(0.4 / p.cycle_s(get_gait('pentapod')))
    bad = tmp_path / 'g.yaml'
    bad.write_text('wave:\n  groups: [[1], [2], [3], [4], [5], [6]]\n  max_turn_rad: true\n')
    with pytest.raises(GaitError, match="gait 'wave': max_turn_rad must be a number"):
        load_gaits(bad)
    with pytest.raises(GaitError, match='max_turn_rad must be a finite positive'):
        Gait('wave', ((1,), (2,), (3,), (4,), (5,), (6,)), 0.09, math.nan)


def test_roll_pitch_yaw_of_known_rotations():
    import math

    from hexapod_locomotion.core.metrics import roll_pitch_yaw
    h = math.sqrt(0.5)
    assert roll_pitch_yaw((1, 0, 0, 0)) == pytest.approx((0, 0, 0))
    assert roll_pitch_yaw((h, h, 0, 0)) == pytest.approx((math.pi / 2, 0, 0))
    assert roll_pitch_yaw((math.cos(0.1), 0, math.sin(0.1), 0)) == pytest.approx((0, 0.2, 0))
    assert roll_pitch_yaw((math.cos(0.3), 0, 0, math.sin(0.3))) == pytest.approx((0, 0, 0.6))


def test_a_turn_on_top_of_the_stride_shortens_the_step():
    """No foothold moves further than the stride per cycle, the turn's part of its path included: the
    step is shortened and the turn kept; a straight step and a turn in place within the gait's limits
    are left as they are; a turn longer than the stride on its own is cut to it."""
    import numpy as np

    from hexapod_locomotion.core.controller import step_within_stride
    from hexapod_locomotion.core.locomotion_params import LocomotionParams
    from hexapod_model.description import load_robot
    from hexapod_model.kinematics import stance_feet
    neutral = stance_feet(load_robot())[:, :2]
    p = LocomotionParams()

    def rot(a):
        return np.array([[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]])

    def widest(d, yaw):      # landing (turned by yaw/2, d/2 ahead) to lift-off (turned back, d/2 behind)
        land = neutral @ rot(yaw / 2).T + d / 2
        lift = neutral @ rot(-yaw / 2).T - d / 2
        return float(np.max(np.linalg.norm(land - lift, axis=1)))

    for name in ('tripod', 'tetrapod', 'pentapod'):
        gait = get_gait(name)
        stride, turn = p.stride_m(gait), p.turn_rad(gait)
        for d in (np.array([stride, 0.0]), np.array([0.6, -0.8]) * stride):
            assert step_within_stride(d, 0.0, stride, neutral) == (d, 0.0)
            for yaw in (0.02, -0.1, turn, -turn):
                d2, yaw2 = step_within_stride(d, yaw, stride, neutral)
                assert yaw2 == yaw
                assert widest(d2, yaw2) == pytest.approx(stride, rel=1e-9)
                k = d2[0] / d[0]
                assert 0 < k < 1 and d2 == pytest.approx(k * d)
        assert step_within_stride(2 * np.array([stride, 0.0]), 0.0, stride, neutral)[0] == pytest.approx([stride, 0])
        assert step_within_stride(np.zeros(2), turn, stride, neutral)[1] == turn
        slow = np.array([0.3 * stride, 0.0])
        assert step_within_stride(slow, 0.05, stride, neutral) == (slow, 0.05)
        d2, yaw2 = step_within_stride(np.array([stride, 0.0]), 1.0, stride, neutral)
        assert not d2.any() and 0 < yaw2 < 1.0 and widest(d2, yaw2) == pytest.approx(stride)
