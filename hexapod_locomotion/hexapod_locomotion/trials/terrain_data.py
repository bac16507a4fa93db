"""Labelled gait cycles for the terrain classifier: from simulated trials (in process) and from bags
with label files. No rclpy.

*Trials* (:func:`trial_cycles`): the trial runner walks the sim on a terrain of
:mod:`hexapod_sim.physics.terrain_classes` and hands every recorded topic to a :class:`StreamTap` instead of
a bag; the tap keeps the streams the features need and the truth of the trunk's x (for the labels
only). The streams of a trial are cached (``TERRAIN_CACHE`` or ``/tmp/hexapod_terrain_cache``,
keyed by the trial, the robot description and the sim's terrain code), so the features can be
reworked without walking again.

*Label files* (:func:`read_labels`), one per bag, ``BAG.labels.txt`` beside the bag directory: one
interval per line, ``START_S END_S LABEL``, times in seconds of the bag's message stamps, ``#``
starts a comment. ``LABEL`` is a terrain class, or ``-`` for "no label" (the cycles there are
neither trained on nor scored). A gait cycle takes the label of the interval that holds its whole
span; a cycle that overlaps two labels or a ``-`` is unlabelled.
"""
from __future__ import annotations

import gzip
import hashlib
import math
import os
import pickle
import re
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from hexapod_locomotion.core.terrain_features import REQUIRED_TOPICS, CycleFeatureExtractor, feed_message
from hexapod_locomotion.core.terrain_model import UNLABELLED
from hexapod_model.contract import (
    GROUND_DETECTION,
    JOINT_COMMANDS,
    JOINT_STATES,
    POWER,
    SIM_TRUTH_POSE,
    SWING_DOWN,
    stamp_seconds,
    topic_key,
)
from hexapod_model.description import LEGS

# the trunk within this distance of a segment boundary: some feet may stand on the other class (the
# front and rear feet are 0.225 m ahead of and behind the trunk, plus half a stride) [m]
BOUNDARY_MARGIN_M = 0.30
# a foot within this distance of a segment boundary over a cycle may stand on either class (half a
# step of 0.05 m plus the foot's slip) [m]
FOOT_MARGIN_M = 0.08
CACHE_FORMAT = 1


class TerrainDataError(ValueError):
    """Bad label file, bag without the needed topics, ... (the message names what is wrong)."""


def cache_dir() -> Path:
    return Path(os.environ.get('TERRAIN_CACHE', '/tmp/hexapod_terrain_cache'))


class StreamTap:
    """A recorder (the methods of :class:`hexapod_sim.bagio.recorder.Recorder`) that keeps, in memory, the
    streams of the terrain features and the truth of the trunk's x, in the order they come."""

    def __init__(self):
        self.events: list[tuple] = []

    def write(self, topic: str, msg_type: str, msg, t_s: float) -> None:
        k = topic_key(topic)
        if k == JOINT_STATES:
            self.events.append(('s', stamp_seconds(msg['header']['stamp']), tuple(msg['name']), tuple(msg['position'])))
        elif k == JOINT_COMMANDS:
            self.events.append(('c', t_s, tuple(msg['name']), tuple(msg['position'])))
        elif k == GROUND_DETECTION:
            self.events.append(('d', t_s, {f: msg[f] for f in ('leg', 't_swing_s', 'theta_des_tick', 'theta_real_tick',
                                                               'err_tick', 'err_est_tick', 'threshold_tick', 'stopped',
                                                               'stop_reason')}))
        elif k == SWING_DOWN:
            self.events.append(('w', t_s, {f: msg[f] for f in ('legs', 'coxa_rad', 'femur_init_rad', 'tibia_init_rad',
                                                               'femur_fin_rad', 'tibia_fin_rad', 't_des_s')}))
        elif k == POWER:
            self.events.append(('p', t_s, abs(float(msg['voltage']) * float(msg['current']))))
        elif k == SIM_TRUTH_POSE:
            self.events.append(('x', t_s, float(msg['pose']['position']['x'])))

    def tf_due(self, t_s: float) -> bool:
        return False

    def write_tf(self, *args, **kwargs) -> None:
        pass

    def close(self) -> None:
        pass


def replay(robot, events) -> list:
    """The gait cycles (:class:`~.terrain_features.CycleFeatures`) of a tap's events."""
    ex = CycleFeatureExtractor(robot)
    cycles = []
    for ev in events:
        kind = ev[0]
        if kind == 's':
            for n, p in zip(ev[2], ev[3]):
                ex.state(ev[1], n, p)
        elif kind == 'c':
            ex.command(ev[2], ev[3])
        elif kind == 'd':
            ex.detection(ev[2])
        elif kind == 'w':
            c = ex.swing_start(ev[1], ev[2])
            if c is not None:
                cycles.append(c)
        elif kind == 'p':
            ex.power(ev[1], ev[2])
    return cycles


def truth_labels(terrain: str, seed: int, events) -> list[tuple[float, float, str]]:
    """Label intervals of a walk from the truth of the trunk's x and the terrain's layout: the class
    of the segment under the trunk, ``-`` within BOUNDARY_MARGIN_M of a boundary."""
    from hexapod_sim.physics.terrain_classes import label_at, layout
    segs = layout(terrain, seed)
    tx = np.array([(e[1], e[2]) for e in events if e[0] == 'x'])
    if len(tx) == 0:
        return []
    edges = np.array([s.x1_m for s in segs[:-1]])
    labels = []
    for t, x in tx:
        near = edges.size and np.min(np.abs(edges - x)) < BOUNDARY_MARGIN_M
        labels.append(UNLABELLED if near else str(label_at(segs, x)[0]))
    out = []
    start = tx[0, 0]
    for i in range(1, len(labels) + 1):
        if i == len(labels) or labels[i] != labels[i - 1]:
            end = tx[i, 0] if i < len(labels) else tx[-1, 0] + 1e-3
            out.append((float(start), float(end), labels[i - 1]))
            if i < len(labels):
                start = tx[i, 0]
    return out


def leg_labels(terrain: str, seed: int, events, cycles, robot) -> list[tuple[str, ...]]:
    """Per cycle, the label of each leg (LEGS order) from the truth of the trunk's x: the class under
    the leg's nominal foot over the whole cycle, ``-`` where the foot comes within FOOT_MARGIN_M of a
    class boundary. Legs of a cycle across a boundary get the class each one stands on."""
    from hexapod_model.kinematics import stance_feet
    from hexapod_sim.physics.terrain_classes import label_at, layout
    segs = layout(terrain, seed)
    tx = np.array([(e[1], e[2]) for e in events if e[0] == 'x'])
    if len(tx) == 0:
        return [(UNLABELLED,) * len(LEGS) for _ in cycles]
    fx = stance_feet(robot)[:, 0]
    edges = np.array([sg.x1_m for sg in segs[:-1]])
    out = []
    for c in cycles:
        x0, x1 = np.interp([c.t_start_s, c.t_end_s], tx[:, 0], tx[:, 1])
        lo, hi = min(x0, x1) + fx - FOOT_MARGIN_M, max(x0, x1) + fx + FOOT_MARGIN_M
        across = [bool(np.any((edges > a) & (edges < b))) for a, b in zip(lo, hi)]
        names = label_at(segs, (lo + hi) / 2)
        out.append(tuple(UNLABELLED if cut else str(n) for cut, n in zip(across, names)))
    return out


def cycle_labels(cycles, intervals) -> list[str]:
    """The label of each cycle: that of the interval holding its whole span, else ``-``."""
    out = []
    for c in cycles:
        lab = UNLABELLED
        for t0, t1, name in intervals:
            if t0 - 1e-9 <= c.t_start_s and c.t_end_s <= t1 + 1e-9:
                lab = name
                break
        out.append(lab)
    return out


def boundary_times(intervals) -> list[tuple[float, str, str]]:
    """(time, class before, class after) where the labelled class changes (across ``-`` gaps)."""
    out, prev = [], None
    for t0, t1, name in intervals:
        if name == UNLABELLED:
            continue
        if prev is not None and name != prev[2]:
            out.append(((prev[1] + t0) / 2, prev[2], name))
        prev = (t0, t1, name)
    return out


# ----------------------------------------------------------------------------- trials
@dataclass(frozen=True)
class TrialSpec:
    terrain: str
    seed: int
    gait: str
    duration_s: float
    overlays: tuple[str, ...] = ()
    t_des_s: float = 1.0


def _code_hash(spec: TrialSpec) -> str:
    import hexapod_sim.physics.terrain as t1
    import hexapod_sim.physics.terrain_classes as t2
    from hexapod_model.description import load_robot
    h = hashlib.sha256(repr((CACHE_FORMAT, asdict(spec))).encode())
    for mod in (t1, t2):
        h.update(Path(mod.__file__).read_bytes())
    h.update(repr(load_robot(overlays=spec.overlays)).encode())
    return h.hexdigest()[:20]


def trial_events(spec: TrialSpec) -> list[tuple]:
    """The tapped streams of one trial, from the cache or by walking it (and caching them)."""
    path = cache_dir() / f'{spec.terrain}_{spec.gait}_s{spec.seed}_{_code_hash(spec)}.pkl.gz'
    if path.exists():
        with gzip.open(path, 'rb') as f:
            return pickle.load(f)
    from hexapod_locomotion.trials.trial_runner import TrialConfig, run_trial
    tap = StreamTap()
    run_trial(TrialConfig(gait=spec.gait, terrain=spec.terrain, seed=spec.seed, duration_s=spec.duration_s,
                          overlays=spec.overlays, t_des_s=spec.t_des_s, course_end_m=None), recorder=tap)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(f'.tmp{os.getpid()}')
    with gzip.open(tmp, 'wb', compresslevel=3) as f:
        pickle.dump(tap.events, f, protocol=pickle.HIGHEST_PROTOCOL)
    os.replace(tmp, path)
    return tap.events


def trial_cycles(spec: TrialSpec) -> dict:
    """Features, labels and times of the gait cycles of one trial (walked or cached; the features are
    cached too, keyed by the feature code as well)."""
    from hexapod_locomotion.core import terrain_features
    from hexapod_model.description import load_robot
    key = hashlib.sha256((_code_hash(spec) + hashlib.sha256(Path(terrain_features.__file__).read_bytes()).hexdigest()
                          + hashlib.sha256(Path(__file__).read_bytes()).hexdigest()).encode()).hexdigest()[:20]
    path = cache_dir() / f'cycles_{spec.terrain}_{spec.gait}_s{spec.seed}_{key}.pkl'
    if path.exists():
        with open(path, 'rb') as f:
            return pickle.load(f)
    events = trial_events(spec)
    robot = load_robot(overlays=spec.overlays)
    cycles = replay(robot, events)
    intervals = truth_labels(spec.terrain, spec.seed, events)
    out = _pack(cycles, intervals, asdict(spec), leg_labels(spec.terrain, spec.seed, events, cycles, robot))
    tmp = path.with_suffix(f'.tmp{os.getpid()}')
    with open(tmp, 'wb') as f:
        pickle.dump(out, f, protocol=pickle.HIGHEST_PROTOCOL)
    os.replace(tmp, path)
    return out


def _pack(cycles, intervals, source, legs=None) -> dict:
    """``legs``: the labels per leg (:func:`leg_labels`); None: each leg takes its cycle's."""
    from hexapod_locomotion.core.terrain_features import FEATURE_NAMES
    x = np.array([c.values for c in cycles]) if cycles else np.zeros((0, len(FEATURE_NAMES)))
    labels = cycle_labels(cycles, intervals)
    return {'X': x, 'labels': labels, 't_start': [c.t_start_s for c in cycles],
            't_end': [c.t_end_s for c in cycles], 'intervals': intervals, 'source': source,
            'leg_labels': legs if legs is not None else [(lab,) * len(LEGS) for lab in labels]}


# ----------------------------------------------------------------------------- bags and label files
_LINE = re.compile(r'^\s*(\S+)\s+(\S+)\s+(\S+)\s*$')


def labels_path(bag: str | os.PathLike) -> Path:
    p = Path(bag)
    return p.parent / f'{p.name.removesuffix(".mcap")}.labels.txt'


def read_labels(path: str | os.PathLike, classes) -> list[tuple[float, float, str]]:
    """The intervals of a label file (see the module doc); an unknown label or a malformed line is a
    :class:`TerrainDataError` naming the file and line."""
    p = Path(path)
    if not p.is_file():
        raise TerrainDataError(f'{p}: no such label file (one line per interval: START_S END_S LABEL)')
    out = []
    for no, line in enumerate(p.read_text(encoding='utf-8', errors='replace').splitlines(), 1):
        line = line.split('#', 1)[0]
        if not line.strip():
            continue
        m = _LINE.match(line)
        if m is None:
            raise TerrainDataError(f'{p}:{no}: expected "START_S END_S LABEL", got {line.strip()!r}')
        try:
            t0, t1 = float(m.group(1)), float(m.group(2))
        except ValueError:
            raise TerrainDataError(f'{p}:{no}: START_S and END_S must be numbers, got {line.strip()!r}') from None
        if not (math.isfinite(t0) and math.isfinite(t1) and t1 > t0):
            raise TerrainDataError(f'{p}:{no}: need finite START_S < END_S, got {t0!r} {t1!r}')
        lab = m.group(3)
        if lab != UNLABELLED and lab not in classes:
            raise TerrainDataError(f'{p}:{no}: unknown label {lab!r}; known: {", ".join(classes)} (or - for none)')
        out.append((t0, t1, lab))
    if not out:
        raise TerrainDataError(f'{p}: no intervals in the label file')
    return sorted(out)


def write_labels(path: str | os.PathLike, intervals, header: str = '') -> None:
    lines = [f'# {x}' for x in header.splitlines()] + ['# START_S END_S LABEL']
    lines += [f'{t0:.3f} {t1:.3f} {lab}' for t0, t1, lab in intervals]
    Path(path).write_text('\n'.join(lines) + '\n', encoding='utf-8')


def bag_messages(path: str | os.PathLike, extra=()):
    """(contract topic, message, log time [s]) of the feature topics (and ``extra``) of a bag, in
    log-time order; a bag that lacks a needed topic is a :class:`TerrainDataError`."""
    import warnings

    from hexapod_locomotion.core.terrain_features import OPTIONAL_TOPICS
    from hexapod_sim.bagio import BagError, BagReader, BagWarning
    with warnings.catch_warnings():
        warnings.simplefilter('ignore', BagWarning)
        try:
            reader = BagReader(path)
            have = {topic_key(t): t for t in reader.topics()}
            missing = [t for t in REQUIRED_TOPICS if t not in have]
            if missing:
                raise TerrainDataError(f'{path}: no {", ".join("/" + m for m in missing)} in the bag - the terrain '
                                       f'features need {", ".join("/" + t for t in REQUIRED_TOPICS)}')
            wanted = [have[t] for t in (*REQUIRED_TOPICS, *OPTIONAL_TOPICS, *extra) if t in have]
            for name, _type, t_ns, msg in reader.messages(topics=wanted):
                yield topic_key(name), msg, t_ns * 1e-9
        except BagError as exc:          # a missing, unreadable or damaged bag: the user's input
            raise TerrainDataError(str(exc)) from None


def bag_cycles(path: str | os.PathLike, robot, classes=None, labels: bool = True) -> dict:
    """Features (and, with ``labels``, the labels of ``BAG.labels.txt``) of the gait cycles of a bag."""
    ex = CycleFeatureExtractor(robot)
    cycles = []
    messages = bag_messages(path)
    first = next(messages, None)            # the bag's topics are checked here, before the label file
    intervals = read_labels(labels_path(path), classes) if labels else []
    for topic, msg, _t in ([first] if first else []):
        feed_message(ex, topic, msg, _t)
    for topic, msg, _t in messages:
        c = feed_message(ex, topic, msg, _t)
        if c is not None:
            cycles.append(c)
    if not cycles:
        raise TerrainDataError(f'{path}: no complete gait cycle in the bag (every leg must swing down once)')
    return _pack(cycles, intervals, {'bag': str(path)})


# ----------------------------------------------------------------------------- the generated sets
GAITS = ('tripod', 'tetrapod', 'pentapod')
# simulated walking time per trial: a pentapod cycle is three times a tripod's
CLASS_TRIAL_S = {'tripod': 24.0, 'tetrapod': 30.0, 'pentapod': 48.0}
COURSE_TRIAL_S = {'tripod': 36.0, 'tetrapod': 50.0, 'pentapod': 84.0}
DAMPED_OVERLAY = str(Path(__file__).parents[1] / 'data' / 'damped_servo.yaml')
# name -> (terrains, seeds, durations, overlays)
SETS = {
    'train': ('classes', (0, 1, 2, 3, 4, 5), CLASS_TRIAL_S, ()),
    'test': ('classes', (10, 11), CLASS_TRIAL_S, ()),
    'courses': ('course', (20, 21, 22), COURSE_TRIAL_S, ()),
    'courses-train': ('course', (0, 1, 2, 3, 4, 5, 12, 13, 14, 15, 16, 23, 25, 29, 32, 36), COURSE_TRIAL_S, ()),
    'damped': ('classes', (10,), CLASS_TRIAL_S, (DAMPED_OVERLAY,)),
    'damped-train': ('classes', (0,), CLASS_TRIAL_S, (DAMPED_OVERLAY,)),
}


def set_specs(name: str) -> list[TrialSpec]:
    """The trials of a generated set (:data:`SETS`), every gait."""
    from hexapod_sim.physics.terrain_classes import CLASSES
    if name not in SETS:
        raise TerrainDataError(f'unknown set {name!r}; known: {", ".join(SETS)}')
    terrains, seeds, durations, overlays = SETS[name]
    names = [f'class_{c}' for c in CLASSES] if terrains == 'classes' else [terrains]
    return [TrialSpec(t, s, g, durations[g], overlays) for g in GAITS for t in names for s in seeds]


def _cycles_job(spec: TrialSpec) -> dict:
    return trial_cycles(spec)


def set_cycles(name: str, jobs: int = 1) -> list[dict]:
    """The gait cycles of every trial of a set (walked in ``jobs`` processes where not cached)."""
    from hexapod_locomotion.trials.executor import map_jobs
    return map_jobs(_cycles_job, set_specs(name), jobs=jobs)
