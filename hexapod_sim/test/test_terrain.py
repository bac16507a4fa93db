"""Terrains of the mockup (paper Fig. 10): selectable by name, seedable, true heights match MuJoCo."""
import math

import mujoco
import numpy as np
import pytest

from hexapod_model.description import load_robot
from hexapod_model.kinematics import stance_feet
from hexapod_sim.physics import terrain as T
from hexapod_sim.physics.mjcf import scene


def test_names_and_bad_input():
    assert set(T.TERRAINS) == {'flat', 'blocks', 'stairs', 'rough', 'mockup'}
    with pytest.raises(T.TerrainError, match='unknown terrain .*known terrains: flat, blocks'):
        T.make_terrain('lava')
    with pytest.raises(T.TerrainError, match='seed'):
        T.make_terrain('rough', seed=-1)


def test_random_terrains_are_seeded():
    for name in ('blocks', 'rough', 'mockup'):
        a, b, c = T.make_terrain(name, 3), T.make_terrain(name, 3), T.make_terrain(name, 4)
        x, y = np.meshgrid(np.linspace(-1, 2.5, 60), np.linspace(-0.5, 0.5, 20))
        assert np.array_equal(a.height_at(x, y), b.height_at(x, y))
        assert not np.array_equal(a.height_at(x, y), c.height_at(x, y))


def test_blocks_are_10cm_with_bounded_height_and_slope():
    ter = T.make_terrain('blocks', 0)
    assert len(ter.boxes) == 8 * 8
    heights, slopes = [], []
    for b in ter.boxes:
        assert b.half_size_m[0] == pytest.approx(0.05, rel=0.01) and b.half_size_m[1] == pytest.approx(0.05, rel=0.01)
        R = np.array(b.rotation)
        top = np.array(b.center_m) + R[:, 2] * b.half_size_m[2]
        assert b.top_height(top[0], top[1]) == pytest.approx(top[2])    # centre of the top face
        heights.append(top[2])
        slopes.append(math.acos(R[2, 2]))
    lo, hi = T.BLOCK_HEIGHT_RANGE_M
    assert lo <= min(heights) and max(heights) <= hi
    assert max(heights) - min(heights) > 0.5 * (hi - lo)            # really variable
    assert max(slopes) <= T.BLOCK_MAX_SLOPE_RAD + 1e-12 and max(slopes) > 0.5 * T.BLOCK_MAX_SLOPE_RAD


def test_stairs_rise_4cm_per_step():
    ter = T.make_terrain('stairs')
    x0 = T.STAIRS_START_X_M
    xs = x0 + T.STEP_TREAD_M * (np.arange(T.STEP_COUNT) + 0.5)
    np.testing.assert_allclose(ter.height_at(xs, np.zeros_like(xs)), 0.04 * (np.arange(T.STEP_COUNT) + 1))
    assert ter.height_at(x0 - 0.01, 0.0) == 0.0


def test_mockup_is_flat_then_blocks_then_stairs_along_x():
    ter = T.make_terrain('mockup', 0)
    y = np.zeros(1)
    assert np.all(ter.height_at(np.linspace(-0.5, 0.55, 30), 0.0) == 0.0)
    bx = np.linspace(T.MOCKUP_BLOCKS_X_M[0] + 0.02, T.MOCKUP_BLOCKS_X_M[1] - 0.02, 40)
    assert np.std(ter.height_at(bx, 0.025)) > 0.005          # y = 0.025: the middle of a block row
    assert ter.height_at(T.MOCKUP_STAIRS_X_M + 0.1, y) == pytest.approx(0.04)
    assert ter.height_at(T.MOCKUP_STAIRS_X_M + 0.5, y) == pytest.approx(0.12)


def test_the_front_feet_stand_on_the_landing_when_a_walk_ends():
    """A walk over the mockup ends when the trunk passes MOCKUP_COURSE_END_M; the front feet (stride
    and all) are then still on the landing, not over its far edge, a drop of three steps."""
    robot = load_robot()
    front = max(f[0] for f in stance_feet(robot)) + 0.06        # neutral foothold + half the longest stride
    ter = T.make_terrain('mockup', 0)
    xs = np.linspace(T.MOCKUP_COURSE_END_M - 0.3, T.MOCKUP_COURSE_END_M + front + 0.02, 20)
    np.testing.assert_allclose(ter.height_at(xs, np.zeros_like(xs)), T.STEP_RISE_M * T.STEP_COUNT)


@pytest.mark.parametrize('name', ['flat', 'blocks', 'stairs', 'rough', 'mockup'])
def test_true_height_matches_mujoco_ray_casts(name):
    robot = load_robot()
    sc = scene(robot, name, seed=1, fixed_base=False)
    m = mujoco.MjModel.from_xml_string(sc.xml)
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    rng = np.random.default_rng(5)
    geomgroup = np.array([1, 0, 0, 0, 0, 0], dtype=np.uint8)     # terrain geoms only (group 0)
    gid = np.zeros(1, dtype=np.int32)
    pts = np.column_stack([rng.uniform(-0.3, 2.2, 300), rng.uniform(-0.38, 0.38, 300)])
    if name == 'rough':
        pts = np.column_stack([rng.uniform(-1.4, 1.4, 300), rng.uniform(-0.9, 0.9, 300)])
    heights = sc.terrain.height_at(pts[:, 0], pts[:, 1])
    for (x, y), want in zip(pts, heights):
        dist = mujoco.mj_ray(m, d, np.array([x, y, 1.0]), np.array([0.0, 0.0, -1.0]), geomgroup, 1, -1, gid)
        # boxes are exact; the height field is triangulated by MuJoCo, interpolated bilinearly here
        tol = 1e-3 if name == 'rough' else 1e-7
        assert 1.0 - dist == pytest.approx(want, abs=tol), (x, y)
