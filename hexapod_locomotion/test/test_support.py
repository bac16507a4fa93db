"""Static support (core.support) and the controller's support margin: with a leg hanging where its
swing-down found no ground, the body is moved over the feet that stay down before the next group lifts."""
import numpy as np
import pytest

from hexapod_locomotion.core.support import support_shift
from hexapod_locomotion.trials.trial_config import TrialConfig
from hexapod_locomotion.trials.trial_runner import run_trial

SQUARE = np.array([[0.1, 0.1], [-0.1, 0.1], [-0.1, -0.1], [0.1, -0.1]])


def test_a_centre_inside_by_the_margin_stays_where_it_is():
    assert np.array_equal(support_shift(SQUARE, 0.05), np.zeros(2))


def test_the_centre_moves_the_least_distance_to_the_margin():
    # the square 0.15 m to the right: the centre goes to its left edge plus the margin
    assert support_shift(SQUARE + [0.15, 0.0], 0.02) == pytest.approx([0.07, 0.0])
    # beyond a corner: to the corner of the square shrunk by the margin
    assert support_shift(SQUARE + [0.2, 0.3], 0.01) == pytest.approx([0.11, 0.21])
    # a triangle whose edge passes 2 cm behind the centre
    tri = np.array([[-0.02, -0.2], [-0.02, 0.2], [-0.3, 0.0]])
    assert support_shift(tri, 0.03) == pytest.approx([-0.05, 0.0])


def test_no_polygon_or_too_narrow_a_one_has_no_answer():
    assert support_shift(SQUARE[:2], 0.01) is None                               # two feet
    assert support_shift(np.array([[0, 0], [0.1, 0], [0.2, 0]]), 0.0) is None    # on one line
    assert support_shift(SQUARE, 0.11) is None                                    # 0.1 m is the most inside


def _tetrapod_blocks(margin):
    return run_trial(TrialConfig(gait='tetrapod', terrain='blocks', seed=0, duration_s=19.0, heading_correction=True,
                                 obstacle_lift_m=0.03, support_margin_m=margin))


def test_a_hanging_leg_does_not_let_the_body_tip_onto_it():
    """Tetrapod over the blocks (seed 0): at 16.8 s leg 1's swing-down finds no ground and the leg hangs
    over its spot; legs 2 and 3 then lift and leave legs 4-6 with the body's centre outside them. In the
    paper's gait the trunk tips toward leg 1 until that leg touches, a foot the legs-only odometry takes
    as standing leaves the ground (sim truth) and its yaw error builds up meanwhile; with the margin the
    body is first moved over legs 4-6."""
    tipped, held = _tetrapod_blocks(0.0), _tetrapod_blocks(0.02)
    assert not any(w.startswith('support:') for w in tipped.warnings)
    moves = [w for w in held.warnings if w.startswith('support:')]
    assert moves and 'over legs 4, 5, 6 before legs 3, 2 lift' in moves[0]
    assert abs(tipped.odometry['legs']['yaw_error_off_ground_deg']) > 5
    assert abs(held.odometry['legs']['yaw_error_off_ground_deg']) < 0.5 * abs(tipped.odometry['legs']['yaw_error_off_ground_deg'])
