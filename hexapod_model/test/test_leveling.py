"""Body leveling (Eq. 8-10): the regression plane and the new body pose."""
import numpy as np
import pytest

from hexapod_model.leveling import LevelingError, fit_plane, level_body


def test_recovers_known_plane_and_aligns_body():
    rng = np.random.default_rng(1)
    xy = rng.uniform(-0.3, 0.3, size=(6, 2))
    a, b, c = 0.15, -0.08, -0.12
    feet = np.column_stack([xy, a * xy[:, 0] + b * xy[:, 1] + c])
    pose, plane = level_body(feet, height_m=0.13)
    assert (plane.a, plane.b, plane.c) == pytest.approx((a, b, c), abs=1e-12)
    normal = np.array([-a, -b, 1]) / np.linalg.norm([-a, -b, 1])
    assert pose.rotation[:, 2] == pytest.approx(normal)
    assert pose.rotation.T @ pose.rotation == pytest.approx(np.eye(3), abs=1e-12)
    assert pose.rotation[1, 0] == pytest.approx(0.0)        # b_x keeps the walking direction (no yaw)
    # body origin is 0.13 m above the plane, over the foot centroid projected onto the plane
    o = pose.position_m
    dist = (o[2] - (a * o[0] + b * o[1] + c)) / np.linalg.norm([-a, -b, 1])
    assert dist == pytest.approx(0.13)
    centroid = feet.mean(axis=0)
    assert (o - 0.13 * normal - centroid) @ pose.rotation[:, 0] == pytest.approx(0.0, abs=1e-12)
    assert (o - 0.13 * normal - centroid) @ pose.rotation[:, 1] == pytest.approx(0.0, abs=1e-12)
    # in the new body frame all feet lie on z = -0.13
    assert pose.to_body(feet)[:, 2] == pytest.approx(-0.13)


def test_noisy_feet_least_squares():
    feet = np.array([[0.25, 0.19, -0.13], [0.25, -0.19, -0.11], [-0.25, 0.19, -0.14],
                     [-0.25, -0.19, -0.12], [0, 0.29, -0.125], [0, -0.29, -0.115]])
    plane = fit_plane(feet)
    resid = feet[:, 2] - (plane.a * feet[:, 0] + plane.b * feet[:, 1] + plane.c)
    design = np.column_stack([feet[:, 0], feet[:, 1], np.ones(6)])
    assert design.T @ resid == pytest.approx(np.zeros(3), abs=1e-12)   # normal equations


def test_degenerate_feet():
    with pytest.raises(LevelingError, match='collinear'):
        fit_plane(np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0.1]], dtype=float))
    with pytest.raises(LevelingError, match='NaN'):
        fit_plane(np.array([[0, 0, 0], [1, 0, 0], [0, 1, np.nan]], dtype=float))
    with pytest.raises(LevelingError, match='at least three'):
        fit_plane(np.zeros((2, 3)))
