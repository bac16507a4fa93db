"""Body leveling (paper Sec. 5, Eq. 8-10). Pure numpy.

Given the foot-tip positions in a reference ("global") frame, fit the regression plane
``z = a x + b y + c`` (least squares), build the body rotation from the plane's basis vectors
(Eq. 9; ``b_x`` keeps the walking direction) and the translation of Eq. 10 (the foot centroid
expressed in that basis). The new body origin is then placed ``height_m`` above the plane along
its normal, so the body keeps the distances *h* and *d* of Fig. 5 to its feet.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


class LevelingError(ValueError):
    """The foot-tips do not define a plane (too few, non-finite, or collinear in x-y)."""


@dataclass(frozen=True)
class Plane:
    """Regression plane ``z = a x + b y + c`` (x, y, z in metres)."""

    a: float
    b: float
    c: float

    @property
    def normal(self) -> np.ndarray:
        n = np.array([-self.a, -self.b, 1.0])
        return n / np.linalg.norm(n)


@dataclass(frozen=True)
class BodyPose:
    """Body pose in the reference frame: ``p_ref = rotation @ p_body + position_m``."""

    rotation: np.ndarray
    position_m: np.ndarray

    def matrix(self) -> np.ndarray:
        m = np.eye(4)
        m[:3, :3] = self.rotation
        m[:3, 3] = self.position_m
        return m

    def to_body(self, points_ref_m: np.ndarray) -> np.ndarray:
        """Express reference-frame points (rows) in this body frame."""
        return (np.asarray(points_ref_m) - self.position_m) @ self.rotation

    def roll_pitch_rad(self) -> tuple[float, float]:
        r = self.rotation
        return float(np.arctan2(r[2, 1], r[2, 2])), float(-np.arcsin(np.clip(r[2, 0], -1, 1)))


def fit_plane(feet_m: np.ndarray) -> Plane:
    """Least-squares plane through the foot-tips (rows of x, y, z)."""
    p = np.asarray(feet_m, dtype=float)
    if p.ndim != 2 or p.shape[1] != 3 or p.shape[0] < 3:
        raise LevelingError(f'need at least three foot-tips as rows of (x, y, z), got shape {p.shape}')
    if not np.all(np.isfinite(p)):
        raise LevelingError('foot-tip positions contain NaN or infinity')
    a_mat = np.column_stack([p[:, 0], p[:, 1], np.ones(len(p))])
    if np.linalg.matrix_rank(a_mat, tol=1e-9) < 3:
        raise LevelingError('foot-tips are collinear in x-y; no unique support plane')
    (a, b, c), *_ = np.linalg.lstsq(a_mat, p[:, 2], rcond=None)
    return Plane(float(a), float(b), float(c))


def plane_basis(plane: Plane) -> np.ndarray:
    """Eq. 9: rotation whose columns are the normalised b_x, b_y, b_z of the plane."""
    a, b = plane.a, plane.b
    bx = np.array([1.0, 0.0, a])
    by = np.array([-a * b, a * a + 1.0, b])
    bz = np.array([-a, -b, 1.0])
    return np.column_stack([bx / np.linalg.norm(bx), by / np.linalg.norm(by), bz / np.linalg.norm(bz)])


def level_body(feet_m: np.ndarray, height_m: float) -> tuple[BodyPose, Plane]:
    """New body pose aligned with the foot-tip regression plane (Eq. 8-10), ``height_m`` above it."""
    if not np.isfinite(height_m):
        raise LevelingError(f'body height must be finite, got {height_m!r}')
    p = np.asarray(feet_m, dtype=float)
    plane = fit_plane(p)
    rot = plane_basis(plane)
    a, b, c = plane.a, plane.b, plane.c
    n = len(p)
    sx, sy, sz = p.sum(axis=0)
    norm_bx = np.sqrt(1 + a * a)
    norm_by = np.sqrt((a * b) ** 2 + (a * a + 1) ** 2 + b * b)
    norm_bz = np.sqrt(a * a + b * b + 1)
    t = np.array([(sx + a * sz) / (n * norm_bx),                                # Eq. 10
                  (-a * b * sx + (a * a + 1) * sy + b * sz) / (n * norm_by),
                  c / norm_bz])
    position = rot @ t + height_m * rot[:, 2]
    return BodyPose(rotation=rot, position_m=position), plane
