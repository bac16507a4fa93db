"""Terrain classification from servo feedback: generate labelled walks, train, evaluate, benchmark.

  generate SET...            walk the simulated trials of generated sets (cached under /tmp)
  train [--set SET] [BAG]    train a model on sets and/or bags with label files (BAG.labels.txt)
  evaluate [--set SET] [BAG] per-gait-cycle accuracy, confusion matrix, class changes on courses
  record BAG --terrain T     walk the sim on a terrain and write a bag with its label file
  bench                      the classifier's time per gait cycle (features + prediction)

Sets (every gait; seeds in brackets): train [0-5] and test [10-11] walk each terrain class,
courses [20-22] and courses-train [0-5, 12-16, 23, 25, 29, 32, 36] the mixed courses; damped [10] and
damped-train [0] walk each class with a servo law of 1.5 x the motor damping (data/damped_servo.yaml).
Label files: one interval per line,
``START_S END_S LABEL`` in the bag's stamps, ``-`` for no label (docs/terrain.md).
"""
from __future__ import annotations

import shlex
import sys
import time
from pathlib import Path

import numpy as np

from hexapod_locomotion.core.terrain_features import FEATURE_NAMES
from hexapod_locomotion.core.terrain_model import (
    DEFAULT_MODEL,
    TerrainModel,
    TerrainModelError,
    accuracy,
    confusion,
    confusion_lines,
    provenance,
)
from hexapod_locomotion.trials.terrain_data import (
    GAITS,
    SETS,
    UNLABELLED,
    TerrainDataError,
    bag_cycles,
    boundary_times,
    labels_path,
    set_cycles,
    set_specs,
    truth_labels,
    write_labels,
)
from hexapod_model.cli_common import (
    add_no_progress_option,
    existing_file,
    interrupted,
    make_parser,
    nonnegative_int,
    output_directory,
    output_file,
    positive_float,
)
from hexapod_model.description import LEGS, DescriptionError, load_robot


def _sets_arg(value: str) -> str:
    if value not in SETS:
        import argparse
        raise argparse.ArgumentTypeError(f'unknown set {value!r}; known: {", ".join(SETS)}')
    return value


def _new_bag(text: str) -> str:
    """argparse type: a bag directory to write: must not exist; missing parents are made."""
    import argparse
    if Path(text).exists():
        raise argparse.ArgumentTypeError(f'{text}: already exists (choose a new bag directory)')
    return output_directory(text)


def build_parser():
    ap = make_parser('terrain', __doc__)
    sub = ap.add_subparsers(dest='cmd', required=True, metavar='COMMAND')
    g = sub.add_parser('generate', help='walk the trials of generated sets (cached)')
    g.add_argument('sets', nargs='+', type=_sets_arg, metavar='SET')
    g.add_argument('--jobs', type=nonnegative_int, default=1, help='worker processes (default 1)')
    t = sub.add_parser('train', help='train a model on generated sets and/or labelled bags')
    t.add_argument('bags', nargs='*', metavar='BAG', help='bags, each with BAG.labels.txt beside it')
    t.add_argument('--set', dest='sets', action='append', type=_sets_arg, default=[], metavar='SET')
    t.add_argument('--out', required=True, type=output_file(create_parent=True), help='model file to write (.pkl.gz); the packaged one is '
                   'hexapod_locomotion/hexapod_locomotion/data/terrain_model.pkl.gz')
    t.add_argument('--classes', help='comma-separated class names the labels may use (default: the sim classes)')
    t.add_argument('--jobs', type=nonnegative_int, default=1)
    e = sub.add_parser('evaluate', help='per-cycle accuracy of a model on sets and/or labelled bags')
    e.add_argument('bags', nargs='*', metavar='BAG')
    e.add_argument('--set', dest='sets', action='append', type=_sets_arg, default=[], metavar='SET')
    e.add_argument('--model', default=str(DEFAULT_MODEL))
    e.add_argument('--jobs', type=nonnegative_int, default=1)
    r = sub.add_parser('record', help='walk the sim and write a bag plus its label file (from the sim truth)')
    r.add_argument('bag', type=_new_bag, help='bag directory to write (must not exist)')
    r.add_argument('--terrain', required=True, help='class_flat ... class_slippery, or course')
    r.add_argument('--seed', type=nonnegative_int, default=0)
    r.add_argument('--gait', default='tripod', choices=GAITS)
    r.add_argument('--duration', type=positive_float, default=30.0, help='simulated walking time [s]')
    r.add_argument('--overlay', action='append', default=[], type=existing_file, help='robot-description overlay (repeatable)')
    b = sub.add_parser('bench', help="the classifier's time per gait cycle")
    b.add_argument('--model', default=str(DEFAULT_MODEL))
    b.add_argument('--repeat', type=nonnegative_int, default=200)
    for p in (g, t, e, r, b):
        add_no_progress_option(p)
    return ap


def main(argv=None) -> int:
    ap = build_parser()
    args = ap.parse_args(argv)
    args.argv = list(sys.argv[1:] if argv is None else argv)
    try:
        return {'generate': _generate, 'train': _train, 'evaluate': _evaluate, 'record': _record,
                'bench': _bench}[args.cmd](args)
    except (TerrainDataError, TerrainModelError, DescriptionError) as exc:
        print(f'{ap.prog} {args.cmd}: error: {exc}', file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return interrupted(f'{ap.prog} {args.cmd}', 'cached trials are kept')


def _classes(args) -> tuple[str, ...]:
    from hexapod_sim.physics.terrain_classes import CLASSES
    if getattr(args, 'classes', None):
        names = tuple(c.strip() for c in args.classes.split(',') if c.strip())
        bad = [c for c in names if not c.replace('_', '').isalnum() or c == UNLABELLED]
        if not names or bad:
            raise TerrainDataError(f'--classes: expected comma-separated names of letters, digits and _, got {args.classes!r}')
        return names
    return CLASSES


def _gather(args, robot, classes, labels=True) -> list[dict]:
    data = []
    for s in args.sets:
        print(f'set {s}: {len(set_specs(s))} trials', file=sys.stderr, flush=True)
        data += set_cycles(s, jobs=max(1, args.jobs))
    for bag in args.bags:
        data.append(bag_cycles(bag, robot, classes, labels=labels))
    if not data:
        raise TerrainDataError('nothing to read: give --set SET and/or BAG arguments')
    return data


def _stack(data):
    x = np.concatenate([d['X'] for d in data]) if data else np.zeros((0, len(FEATURE_NAMES)))
    y = np.concatenate([np.asarray(d['labels'], dtype=object) for d in data]) if data else np.zeros(0)
    return x, y


def _group(d: dict) -> str:
    """The cross-validation group of a trial or bag: its seed (the walks of one seed share the terrain
    draws) or the bag."""
    src = d['source']
    return f'seed {src["seed"]}' if 'seed' in src else str(src.get('bag'))


def _generate(args) -> int:
    for s in args.sets:
        t0 = time.monotonic()
        data = set_cycles(s, jobs=max(1, args.jobs))
        n = sum(len(d['labels']) for d in data)
        print(f'{s}: {len(data)} trials, {n} gait cycles ({time.monotonic() - t0:.0f} s)')
    return 0


def _train(args) -> int:
    robot = load_robot()
    classes = _classes(args)
    data = _gather(args, robot, classes)
    x, y = _stack(data)
    groups = np.concatenate([[_group(d)] * len(d['labels']) for d in data])
    legs = np.concatenate([np.asarray(d['leg_labels'], dtype=object).reshape(-1, len(LEGS)) for d in data])
    keep = y != UNLABELLED
    sources = [{'set': s, 'trials': [f'{sp.terrain} seed {sp.seed} {sp.gait} {sp.duration_s:g} s'
                                     + (f' overlays {list(sp.overlays)}' if sp.overlays else '')
                                     for sp in set_specs(s)]} for s in args.sets]
    sources += [{'bag': str(b), 'labels': str(labels_path(b))} for b in args.bags]
    cmd = './hexapod terrain ' + ' '.join(shlex.quote(a) for a in args.argv)
    model = TerrainModel.fit(x, y, provenance(cmd, sources), groups=groups, leg_labels=legs)
    unknown = sorted(set(model.classes) - set(classes))
    if unknown:
        raise TerrainDataError(f'labels {unknown} are not among the classes {list(classes)}')
    path = model.save(args.out)
    counts = ', '.join(f'{c} {n}' for c, n in model.provenance['cycles_per_class'].items())
    print(f'trained on {int(keep.sum())} labelled gait cycles ({counts}); model: {path} '
          f'({path.stat().st_size / 1024:.0f} KiB, code {model.provenance["code_version"]}, probability '
          f'temperature {model.provenance["temperature"]:.2f})')
    return 0


def predict_data(model: TerrainModel, data: list[dict]) -> list[np.ndarray]:
    return [model.predict(d['X'])[0] if len(d['X']) else np.zeros(0, dtype=object) for d in data]


def change_lags(data, predicted) -> list[int | None]:
    """Per class change of a walk: gait cycles from the first cycle that ends after the trunk crosses
    the boundary until the first one classed as the new class (0: at once); None if never."""
    lags = []
    for d, pred in zip(data, predicted):
        for t_b, _old, new in boundary_times(d['intervals']):
            after = [i for i, t in enumerate(d['t_end']) if t > t_b]
            hit = next((k for k, i in enumerate(after) if pred[i] == new), None)
            lags.append(hit)
    return lags


def _evaluate(args) -> int:
    model = TerrainModel.load(args.model)
    robot = load_robot()
    data = _gather(args, robot, model.classes)
    pred = predict_data(model, data)
    y = np.concatenate([np.asarray(d['labels'], dtype=object) for d in data])
    p = np.concatenate(pred)
    keep = y != UNLABELLED
    classes = list(model.classes)
    m = confusion(y[keep], p[keep], classes)
    print(f'model {args.model} (code {model.provenance.get("code_version")}, {model.provenance.get("date")})')
    print(f'per gait cycle: {accuracy(m) * 100:.1f} % of {int(m.sum())} labelled cycles '
          f'({int((~keep).sum())} cycles across a class boundary not scored)')
    gaits = [d['source'].get('gait', 'bag') for d in data]
    for g in dict.fromkeys(gaits):
        sel = [i for i, gg in enumerate(gaits) if gg == g]
        yy = np.concatenate([np.asarray(data[i]['labels'], dtype=object) for i in sel])
        pp = np.concatenate([pred[i] for i in sel])
        k = yy != UNLABELLED
        mg = confusion(yy[k], pp[k], classes)
        print(f'  {g}: {accuracy(mg) * 100:.1f} % of {int(mg.sum())}')
    for line in confusion_lines(m, classes):
        print(line)
    _calibration_line(model, data, y, keep)
    lags = change_lags(data, pred)
    if lags:
        ok = sum(1 for v in lags if v is not None and v <= 1)
        hist = {}
        for v in lags:
            hist['never' if v is None else str(v)] = hist.get('never' if v is None else str(v), 0) + 1
        print(f'class changes: {len(lags)}; detected within two gait cycles of the trunk crossing the boundary: '
              f'{ok} ({100 * ok / len(lags):.0f} %); cycles of delay: '
              + ', '.join(f'{k}: {v}' for k, v in sorted(hist.items())))
    return 0


def _calibration_line(model: TerrainModel, data, y, keep) -> None:
    """How well the published confidence matches: its mean against the accuracy, and the log loss."""
    x = np.concatenate([d['X'] for d in data if len(d['X'])])
    probs = model.probabilities(x)[keep]
    names = [str(c) for c in model.estimator.classes_]
    known = np.isin(y[keep], names)
    if not known.any():
        return
    probs, truth = probs[known], np.array([names.index(t) for t in y[keep][known]])
    hit = probs.argmax(axis=1) == truth
    loss = -np.mean(np.log(np.clip(probs[np.arange(len(truth)), truth], 1e-12, 1.0)))
    print(f'confidence: mean {100 * probs.max(axis=1).mean():.1f} % (accuracy {100 * hit.mean():.1f} %); '
          f'{100 * probs.max(axis=1)[hit].mean():.1f} % when right, '
          + (f'{100 * probs.max(axis=1)[~hit].mean():.1f} % when wrong' if (~hit).any() else 'never wrong')
          + f'; log loss {loss:.3f}')


def _record(args) -> int:
    from hexapod_locomotion.trials.trial_runner import TrialConfig, run_trial
    from hexapod_sim.physics.terrain_classes import CLASS_TERRAINS
    if args.terrain not in CLASS_TERRAINS:
        raise TerrainDataError(f'--terrain: unknown terrain class terrain {args.terrain!r}; known: '
                               f'{", ".join(CLASS_TERRAINS)}')
    bag = Path(args.bag)
    if bag.exists():
        raise TerrainDataError(f'{bag}: exists; give a new bag directory')
    load_robot(overlays=args.overlay)          # a bad overlay: one line before anything is written
    cfg = TrialConfig(gait=args.gait, terrain=args.terrain, seed=args.seed, duration_s=args.duration,
                      overlays=tuple(args.overlay), record=str(bag))
    res = run_trial(cfg)
    events = [('x', msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9, msg.pose.position.x)
              for _k, msg, _t in _truth_pose(bag)]
    lab = labels_path(bag)
    write_labels(lab, truth_labels(args.terrain, args.seed, events),
                 f'labels of {bag.name} from the sim truth: ./hexapod terrain record {" ".join(sys.argv[2:])}')
    print(f'bag: {bag} ({res.sim_time_s:.1f} s walked, {res.distance_m:.2f} m); labels: {lab}')
    return 0


def _truth_pose(bag):
    import warnings

    from hexapod_model.contract import SIM_TRUTH_POSE, topic_key
    from hexapod_sim.bagio import BagReader, BagWarning
    with warnings.catch_warnings():
        warnings.simplefilter('ignore', BagWarning)
        reader = BagReader(bag)
        names = [t for t in reader.topics() if topic_key(t) == SIM_TRUTH_POSE]
        for name, _type, t_ns, msg in reader.messages(topics=names):
            yield topic_key(name), msg, t_ns * 1e-9


def _bench(args) -> int:
    """Replays one generated trial's streams through the feature extractor and times it per gait
    cycle, then times one prediction per cycle."""
    from hexapod_locomotion.trials.terrain_data import TrialSpec, replay, trial_events
    model = TerrainModel.load(args.model)
    robot = load_robot()
    print('gait       cycles  features per cycle [ms]  prediction per cycle [ms]  streams per cycle')
    for gait in GAITS:
        spec = TrialSpec('class_rough', 10, gait, 24.0 if gait == 'tripod' else 30.0 if gait == 'tetrapod' else 48.0)
        events = trial_events(spec)
        t0 = time.perf_counter()
        cycles = replay(robot, events)
        t_feat = (time.perf_counter() - t0) / max(1, len(cycles))
        x = np.array([c.values for c in cycles])
        times = []
        for k in range(max(1, args.repeat)):
            row = x[k % len(x)][None, :]
            t1 = time.perf_counter()
            model.predict(row)
            times.append(time.perf_counter() - t1)
        n_ev = len(events) / max(1, len(cycles))
        print(f'{gait:9s}  {len(cycles):6d}  {t_feat * 1e3:23.2f}  {np.median(times) * 1e3:14.2f} '
              f'(p99 {np.percentile(times, 99) * 1e3:.2f})  {n_ev:10.0f} messages')
    return 0


if __name__ == '__main__':
    sys.exit(main())
