"""The terrain classifier: a scikit-learn model over the gait-cycle features, saved with its
provenance. No rclpy.

A model file (``.pkl.gz``, a gzip-compressed Python pickle: load only files you trust) holds a mapping: the format tag,
:data:`~.terrain_features.FEATURES_VERSION` and the feature names it was trained on, the
scikit-learn version, the classes, the provenance (the command that made it, the trials or bags and
their seeds, ``git describe`` of the code, the date, the cycles per class) and the estimator. A file
of another format, feature version or scikit-learn version is refused (:class:`TerrainModelError`,
one line): retrain it with ``./hexapod terrain train``.
"""
from __future__ import annotations

import datetime
import gzip
import math
import os
import pickle
import subprocess
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from hexapod_locomotion.core.terrain_estimator import CycleLegClassifier, fit_temperature
from hexapod_locomotion.core.terrain_features import CYCLE_FEATURE_NAMES, FEATURE_NAMES, FEATURES_VERSION, LEG_FEATURES
from hexapod_model.description import LEGS

FORMAT = 'hexapod-terrain-model'
UNLABELLED = '-'           # the label of a cycle or leg that is neither trained on nor scored
DEFAULT_MODEL = Path(__file__).parents[1] / 'data' / 'terrain_model.pkl.gz'


class TerrainModelError(ValueError):
    """A model file that cannot be used (the message says why), or bad training data."""


# Chosen by leave-one-seed-out cross-validation over the training seeds (0-5: the train and
# courses-train sets) only, on the class walks' cycles classed right and on the courses' class changes
# seen within two gait cycles of the trunk crossing: the cycle model at a tenth of the legs' weight, a
# front leg three times a middle one, 50 trees per class of 15 leaves over 63 bins: 96.7 % of 606 cycles
# and 21 of 31 changes, against 95.9 % and 12 for the cycle model alone and 96.5 % and 12 for the same
# model trained without the courses' legs; a front leg 5 times a middle one: 96.2 % and 21. Twice the
# trees (a file twice as large) classed about as many cycles right. With the features of version 5 and
# the courses of seeds 12-16 as well (11 seeds left out in turn), the same settings: 96.7 % of 606 cycles and
# 42 of 59 changes, 7 of the 17 onto flat ground; with the error's growth before the stop as a feature
# too, 96.7 % and 39, 4 onto flat; with it but without the stop time, 94.7 % and 42.
# With the courses of seeds 23, 25, 29, 32 and 36 as well (seeds 23-36 whose course changes from soft
# or slippery onto flat ground) and the cycle's posture and swing-down features in every leg's row
# (LEG_CONTEXT), four folds of the training seeds: 96.0 % of 606 cycles and 70 of 87 changes within two
# cycles, 24 of the 31 onto flat ground; without LEG_CONTEXT 95.9 %, 66 and 18; with every cycle
# feature 95.2 %, 71 and 23. Trained without seed 0, the damped servo law's walks of seed 0
# (damped-train): 93 % of 100 cycles with LEG_CONTEXT, 88 % with every cycle feature (the stance
# errors in ticks depend on the servo law).
CYCLE_WEIGHT = 0.1
FRONT_WEIGHT = 3.0
TREE_PARAMS = {'max_iter': 50, 'learning_rate': 0.2, 'max_leaf_nodes': 15, 'min_samples_leaf': 5, 'max_bins': 63}
LEG_CONTEXT = tuple(n for n in CYCLE_FEATURE_NAMES if n.startswith(
    ('swing_t_stop', 'swing_contact_step', 'swing_no_ground', 'level_', 'legs_per_phase', 'cycle_s_per_t_des')))


def make_estimator(seed: int = 0, temperature: float = 1.0) -> CycleLegClassifier:
    """The cycle-and-leg classifier of :mod:`.terrain_estimator` with the chosen weights."""
    return CycleLegClassifier(len(CYCLE_FEATURE_NAMES), len(LEG_FEATURES), legs=len(LEGS), cycle_weight=CYCLE_WEIGHT,
                              front_weight=FRONT_WEIGHT, temperature=temperature, seed=seed, tree_params=TREE_PARAMS,
                              leg_context=[CYCLE_FEATURE_NAMES.index(n) for n in LEG_CONTEXT])


def cross_temperature(x: np.ndarray, y: np.ndarray, leg_y, groups, seed: int = 0) -> float:
    """The softmax temperature that calibrates the probabilities, fitted on out-of-group scores (each
    group - a seed of the generated walks, a bag - scored by a model trained on the others); 1 with
    fewer than two groups."""
    groups = np.asarray(groups)
    names = list(dict.fromkeys(groups.tolist()))
    if len(names) < 2:
        return 1.0
    scores, truth = [], []
    for g in names:
        tr, te = groups != g, groups == g
        if len(set(y[tr].tolist()) - {UNLABELLED}) < 2:
            continue
        est = make_estimator(seed).fit(x[tr], y[tr], leg_y[tr], skip=UNLABELLED)
        known = np.isin(y[te], est.classes_)
        scores.append(est.log_scores(x[te][known]))
        truth.append(np.searchsorted(est.classes_, y[te][known]))
    if not scores or not sum(len(t) for t in truth):
        return 1.0
    return fit_temperature(np.concatenate(scores), np.concatenate(truth))


def code_version(root: Path | None = None) -> str:
    """``git describe --always --dirty`` of the checkout this code runs from ('unknown' outside git)."""
    root = root or Path(__file__).resolve().parent
    try:
        out = subprocess.run(['git', 'describe', '--always', '--dirty', '--tags'], cwd=root, capture_output=True,
                             text=True, timeout=10)
        return out.stdout.strip() or 'unknown'
    except (OSError, subprocess.SubprocessError):
        return 'unknown'


@dataclass
class TerrainModel:
    estimator: object
    classes: tuple[str, ...]
    provenance: dict

    @classmethod
    def fit(cls, x: np.ndarray, labels, provenance: dict, seed: int = 0, groups=None, leg_labels=None) -> 'TerrainModel':
        """``labels`` per cycle (UNLABELLED: not trained on), ``leg_labels`` (cycles, legs) per leg (None:
        the cycle's); ``groups``: per row, the seed or bag it came from (for the temperature's
        cross-validation)."""
        y = np.asarray(labels, dtype=object)
        leg_y = np.repeat(y[:, None], len(LEGS), axis=1) if leg_labels is None else np.asarray(leg_labels, dtype=object)
        keep = y != UNLABELLED
        if not keep.any():
            raise TerrainModelError('no labelled gait cycles to train on')
        classes = tuple(sorted(set(y[keep].tolist())))
        if len(classes) < 2:
            raise TerrainModelError(f'training needs at least two classes, got {list(classes)}')
        extra = sorted(set(leg_y.reshape(-1).tolist()) - set(classes) - {UNLABELLED})
        if extra:
            raise TerrainModelError(f'leg labels {extra} are not among the cycles\' classes {list(classes)}')
        x = np.asarray(x, dtype=float)
        t = cross_temperature(x, y, leg_y, np.zeros(len(y)) if groups is None else np.asarray(groups), seed)
        est = make_estimator(seed, temperature=t).fit(x, y, leg_y, skip=UNLABELLED)
        counts = {c: int(np.sum(y == c)) for c in classes}
        legs = {c: int(np.sum(leg_y == c)) for c in classes}
        return cls(est, classes, {**provenance, 'cycles_per_class': counts, 'legs_per_class': legs, 'temperature': t})

    def predict(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(class per row, confidence per row: the predicted class's probability)."""
        p = self.probabilities(x)
        idx = np.argmax(p, axis=1)
        names = np.asarray(self.estimator.classes_)
        return names[idx], p[np.arange(len(idx)), idx]

    def probabilities(self, x: np.ndarray) -> np.ndarray:
        """Class probabilities per row, in ``estimator.classes_`` order. On one thread: a gait cycle is one
        row, and the OpenMP team scikit-learn would start for it cost 0.1-0.3 s median on a loaded
        2-core machine (``./hexapod terrain bench``)."""
        from threadpoolctl import threadpool_limits
        with threadpool_limits(limits=1, user_api='openmp'):
            return self.estimator.predict_proba(np.atleast_2d(np.asarray(x, dtype=float)))

    def save(self, path: str | os.PathLike) -> Path:
        import sklearn
        data = {'format': FORMAT, 'features_version': FEATURES_VERSION, 'feature_names': list(FEATURE_NAMES),
                'sklearn_version': sklearn.__version__, 'classes': list(self.classes), 'provenance': self.provenance,
                'estimator': self.estimator}
        p = Path(path)
        p.parent.mkdir(parents=True, exist_ok=True)
        tmp = p.with_name(f'.{p.name}.tmp{os.getpid()}')
        try:
            with gzip.open(tmp, 'wb') as f:
                pickle.dump(data, f, protocol=pickle.HIGHEST_PROTOCOL)
            os.replace(tmp, p)
        finally:
            if tmp.exists():
                tmp.unlink()
        return p

    @classmethod
    def load(cls, path: str | os.PathLike = DEFAULT_MODEL) -> 'TerrainModel':
        import sklearn
        p = Path(path)
        if not p.is_file():
            raise TerrainModelError(f'{p}: no such model file')
        try:
            with gzip.open(p, 'rb') as f:
                data = pickle.load(f)
        except Exception as exc:      # noqa: BLE001 - any unpickling failure: not a model file of this code
            raise TerrainModelError(f'{p}: not a terrain model file of this version ({type(exc).__name__}: '
                                    f'{" ".join(str(exc).split())[:120]}); retrain with ./hexapod terrain train') from None
        if not isinstance(data, dict) or data.get('format') != FORMAT:
            raise TerrainModelError(f'{p}: not a terrain model file (no {FORMAT!r} format tag)')
        if data.get('features_version') != FEATURES_VERSION or list(data.get('feature_names', ())) != list(FEATURE_NAMES):
            raise TerrainModelError(f'{p}: made for terrain features version {data.get("features_version")!r}, this code '
                                    f'computes version {FEATURES_VERSION}; retrain with ./hexapod terrain train')
        if data.get('sklearn_version') != sklearn.__version__:
            raise TerrainModelError(f'{p}: made with scikit-learn {data.get("sklearn_version")!r}, this is '
                                    f'{sklearn.__version__}; retrain with ./hexapod terrain train')
        return cls(data['estimator'], tuple(data['classes']), dict(data.get('provenance', {})))


def provenance(command: str, sources, **extra) -> dict:
    return {'command': command, 'sources': sources, 'code_version': code_version(),
            'date': datetime.date.today().isoformat(), **extra}


# ----------------------------------------------------------------------------- scoring
def confusion(truth, predicted, classes) -> np.ndarray:
    """Confusion counts: rows the true class, columns the predicted, in ``classes`` order."""
    idx = {c: i for i, c in enumerate(classes)}
    m = np.zeros((len(classes), len(classes)), dtype=int)
    for t, p in zip(truth, predicted):
        if t in idx and p in idx:
            m[idx[t], idx[p]] += 1
    return m


def confusion_lines(m: np.ndarray, classes) -> list[str]:
    """The confusion matrix as a Markdown table (rows: true class; columns: predicted)."""
    w = max(9, *(len(c) for c in classes))
    lines = ['| true \\ predicted | ' + ' | '.join(f'{c:>{w}}' for c in classes) + ' | recall |',
             '|---|' + '---:|' * (len(classes) + 1)]
    for i, c in enumerate(classes):
        n = m[i].sum()
        rec = f'{100 * m[i, i] / n:.1f} %' if n else 'n/a'
        lines.append(f'| {c} | ' + ' | '.join(f'{v:>{w}d}' for v in m[i]) + f' | {rec} |')
    return lines


def accuracy(m: np.ndarray) -> float:
    n = m.sum()
    return float(np.trace(m) / n) if n else math.nan
