"""The terrain classifier's estimator: a gait cycle's class from the whole cycle and from each leg.
No rclpy.

Two histogram gradient-boosted tree models (scikit-learn; missing features, e.g. no ``/power``, are
handled natively): one over the whole cycle's features (:data:`~.terrain_features.CYCLE_FEATURE_NAMES`)
and one over a single leg's (:data:`~.terrain_features.LEG_FEATURES`, the leg's nominal foot position
among them), trained on every leg of every cycle with the cycle's label. A cycle's class
log-probability is ``cycle_weight`` times the cycle model's plus the weighted mean of its legs'; a leg
weighs ``front_weight ** (x / x_max)`` (its nominal foot x over the frontmost's): the front legs step
on a new class first, so weighting them lets the class change sooner when the robot walks onto it.
The sum is divided by ``temperature`` before the softmax, fitted so the probabilities are calibrated
(see :func:`fit_temperature`). The leg model may be trained with a label per leg: on a walk across
class boundaries the legs of one cycle stand on different classes, and so learn how a leg on the new
class feels while the others are still on the old. With ``leg_context`` (indices of cycle features) the
leg model sees those of the leg's cycle beside the leg's own: how a foot on flat ground meets it depends
on the posture the other legs hold the body in (after soft ground the body stands lower and tilted for a few cycles, and
a front foot on flat ground then stops where a foot on rough ground would on level support).
"""
from __future__ import annotations

import numpy as np

LOG_FLOOR = 1e-6          # probabilities are clipped here before the log (one model's zero is no veto)


def boosted_trees(seed: int = 0, **params):
    from sklearn.ensemble import HistGradientBoostingClassifier
    p = {'max_iter': 200, 'learning_rate': 0.1, 'max_leaf_nodes': 15, 'min_samples_leaf': 5, **params}
    return HistGradientBoostingClassifier(random_state=seed, **p)


class CycleLegClassifier:
    """``fit(X, y)`` / ``predict_proba(X)`` / ``classes_`` over rows of the cycle features followed by
    ``legs`` blocks of ``n_leg`` leg features, the nominal foot x first in each block (see the module doc)."""

    def __init__(self, n_cycle: int, n_leg: int, legs: int = 6, cycle_weight: float = 1.0, front_weight: float = 1.0,
                 temperature: float = 1.0, seed: int = 0, tree_params: dict | None = None, leg_context=()):
        self.n_cycle, self.n_leg, self.legs, self.leg_context = n_cycle, n_leg, legs, tuple(leg_context)
        self.cycle_weight, self.front_weight, self.temperature = cycle_weight, front_weight, temperature
        self.seed, self.tree_params = seed, dict(tree_params or {})

    def _leg_rows(self, x: np.ndarray) -> np.ndarray:
        """One row per leg: its block, then the ``leg_context`` features of its cycle."""
        rows = x[:, self.n_cycle:self.n_cycle + self.legs * self.n_leg].reshape(len(x) * self.legs, self.n_leg)
        ctx = list(getattr(self, 'leg_context', ()))      # none in a model file saved before the option
        if not ctx:
            return rows
        return np.concatenate([rows, np.repeat(x[:, ctx], self.legs, axis=0)], axis=1)

    def fit(self, x, y, leg_y=None, skip: str = '-') -> 'CycleLegClassifier':
        """``y``: the class per row, ``leg_y`` (rows, legs): per leg (default: the row's); a label ``skip``
        trains nothing (the cycle model skips such a row, the leg model such a leg)."""
        x, y = np.asarray(x, dtype=float), np.asarray(y, dtype=object)
        leg_y = np.repeat(y, self.legs) if leg_y is None else np.asarray(leg_y, dtype=object).reshape(-1)
        rows, legs = y != skip, leg_y != skip
        self.cycle_model_ = boosted_trees(self.seed, **self.tree_params).fit(x[rows, :self.n_cycle], y[rows].astype(str))
        self.leg_model_ = boosted_trees(self.seed, **self.tree_params).fit(self._leg_rows(x)[legs],
                                                                           leg_y[legs].astype(str))
        if list(self.leg_model_.classes_) != list(self.cycle_model_.classes_):
            raise ValueError('the leg and cycle models have different classes')
        self.classes_ = self.cycle_model_.classes_
        return self

    def leg_weights(self, x: np.ndarray) -> np.ndarray:
        """(rows, legs) weights, summing to 1 per row, from each leg's nominal foot x."""
        fx = x[:, self.n_cycle:self.n_cycle + self.legs * self.n_leg:self.n_leg]
        scale = np.max(np.abs(fx), axis=1, keepdims=True)
        w = np.power(self.front_weight, np.divide(fx, scale, out=np.zeros_like(fx), where=scale > 0))
        return w / w.sum(axis=1, keepdims=True)

    def log_scores(self, x) -> np.ndarray:
        """The combined class log-probabilities before the temperature, (rows, classes)."""
        x = np.atleast_2d(np.asarray(x, dtype=float))
        cyc = np.log(np.clip(self.cycle_model_.predict_proba(x[:, :self.n_cycle]), LOG_FLOOR, 1.0))
        leg = np.log(np.clip(self.leg_model_.predict_proba(self._leg_rows(x)), LOG_FLOOR, 1.0))
        leg = leg.reshape(len(x), self.legs, -1)
        return self.cycle_weight * cyc + np.einsum('rlc,rl->rc', leg, self.leg_weights(x))

    def predict_proba(self, x) -> np.ndarray:
        return softmax(self.log_scores(x) / self.temperature)

    def predict(self, x) -> np.ndarray:
        return self.classes_[np.argmax(self.log_scores(x), axis=1)]


def softmax(z: np.ndarray) -> np.ndarray:
    z = z - z.max(axis=1, keepdims=True)
    e = np.exp(z)
    return e / e.sum(axis=1, keepdims=True)


def fit_temperature(scores: np.ndarray, truth_idx: np.ndarray) -> float:
    """The temperature that minimises the log loss of ``softmax(scores / T)`` on held-out rows (their
    true class indices ``truth_idx``), searched on a log grid 0.25-8."""
    grid = np.exp(np.linspace(np.log(0.25), np.log(8.0), 41))
    rows = np.arange(len(truth_idx))
    losses = [-np.mean(np.log(np.clip(softmax(scores / t)[rows, truth_idx], 1e-12, 1.0))) for t in grid]
    return float(grid[int(np.argmin(losses))])
