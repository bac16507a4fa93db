"""Terrain classes and mixed courses: seeded, laid out along x, contact per class, true heights match MuJoCo."""
import mujoco
import numpy as np
import pytest

from hexapod_model.description import load_robot
from hexapod_sim.physics import terrain as T
from hexapod_sim.physics import terrain_classes as C
from hexapod_sim.physics.mjcf import scene

NAMES = [f'class_{c}' for c in C.CLASSES] + ['course']


def test_every_class_and_the_course_are_terrains_and_the_mockup_ones_are_unchanged():
    assert set(NAMES) <= set(T.all_terrains())
    assert set(T.TERRAINS) == {'flat', 'blocks', 'stairs', 'rough', 'mockup'}
    for name in T.TERRAINS:          # no contact override and the floor at z = 0: the scenes of before
        xml = T.make_terrain(name, 1).mjcf_geoms()
        assert 'priority' not in xml and 'solref' not in xml
        assert T.make_terrain(name, 1).floor_z_m == 0.0
    with pytest.raises(T.TerrainError, match="unknown terrain 'class_lava'"):
        T.make_terrain('class_lava')


@pytest.mark.parametrize('name', NAMES)
def test_seeded_variations(name):
    a, b, c = C.layout(name, 3), C.layout(name, 3), C.layout(name, 4)
    assert a == b and a != c
    x, y = np.meshgrid(np.linspace(-0.5, 2.0, 40), np.linspace(-0.3, 0.3, 10))
    assert np.array_equal(T.make_terrain(name, 3).height_at(x, y), T.make_terrain(name, 3).height_at(x, y))


def test_class_contacts_in_the_mjcf():
    soft = T.make_terrain('class_soft', 2)
    seg = C.layout('class_soft', 2)[0]
    xml = soft.mjcf_geoms()
    assert f'solref="{seg.param("timeconst_s"):.10g} 1"' in xml and 'priority="1"' in xml
    lo, hi = C.SOFT_TIMECONST_RANGE_S
    assert lo <= seg.param('timeconst_s') <= hi
    slip = C.layout('class_slippery', 2)[0].param('friction')
    assert C.SLIPPERY_FRICTION_RANGE[0] <= slip <= C.SLIPPERY_FRICTION_RANGE[1]
    assert f'friction="{slip:.6g} 0.005 0.0001"' in T.make_terrain('class_slippery', 2).mjcf_geoms()


def test_courses_change_class_at_every_segment():
    for seed in range(20):
        segs = C.layout('course', seed)
        assert len(segs) == C.COURSE_SEGMENTS
        assert all(a.label != b.label for a, b in zip(segs, segs[1:]))
        assert all(a.x1_m == b.x0_m for a, b in zip(segs, segs[1:]))
        assert segs[0].label in ('flat', 'soft', 'slippery')      # the robot starts on level ground
        assert [s.label for s in segs].count('rough') <= 1
        mids = [(s.x0_m + s.x1_m) / 2 if s.x1_m < 3 else s.x0_m + 0.3 for s in segs]
        assert list(C.label_at(segs, mids)) == [s.label for s in segs]


@pytest.mark.parametrize('name', ['class_rough', 'class_blocks', 'course'])
def test_true_height_matches_mujoco_ray_casts(name):
    sc = scene(load_robot(), name, seed=5)
    m = mujoco.MjModel.from_xml_string(sc.xml)
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    rng = np.random.default_rng(5)
    gid = np.zeros(1, dtype=np.int32)
    pts = np.column_stack([rng.uniform(-0.5, 2.1, 200), rng.uniform(-0.38, 0.38, 200)])
    heights = sc.terrain.height_at(pts[:, 0], pts[:, 1])
    for (x, y), want in zip(pts, heights):
        dist = mujoco.mj_ray(m, d, np.array([x, y, 1.0]), np.array([0.0, 0.0, -1.0]),
                             np.array([1, 0, 0, 0, 0, 0], dtype=np.uint8), 1, -1, gid)
        assert 1.0 - dist == pytest.approx(want, abs=1e-3), (x, y)
