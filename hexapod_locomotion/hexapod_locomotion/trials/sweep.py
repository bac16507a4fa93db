"""./hexapod experiment sweep - one trial parameter over a list of values, one JSON and one plot.

Any field of :class:`hexapod_locomotion.trials.trial_runner.TrialConfig` that describes the walk can be swept:
``epsilon_tick``, ``t_des_s``, ``gait``, ``detector``, ``terrain``, ``vx_mps``, ``fixed_threshold_tick``,
``t_com_s``, ``overlays`` (each value a robot-description overlay YAML, several joined by commas,
``none`` for the plain description), ... The other fields keep the values of the base walk given by
the options (the Table 4 mockup walk by default). Every value runs ``--trials`` seeds (0..N-1) on the
same executors as the other experiments (processes, or Ray tasks with ``--ray``), deterministic per
seed. Example::

    ./hexapod experiment sweep epsilon_tick 2 3 5 --trials 3 --duration 60
"""
from __future__ import annotations

import json
import math
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

from hexapod_locomotion.trials.executor import ExecutorError, JobsInterrupted, add_executor_options, map_jobs
from hexapod_locomotion.trials.trial_runner import DETECTORS, GAITS, TrialConfig, trial_job
from hexapod_model.cli_common import (
    add_no_progress_option,
    interrupted,
    make_parser,
    output_directory,
    positive_float,
    positive_int,
)
from hexapod_model.param_schema import ParameterError, ParamSpec, specs, validate
from hexapod_sim.physics.terrain import MOCKUP_COURSE_END_M

NOT_SWEPT = ('seed', 'record', 'video', 'video_fps')    # seeds are --trials; the rest are outputs
METRICS = (  # (key in a value's summary, axis label)
    ('cot', 'cost of transport (Eq. 18)'),
    ('speed_mps', 'speed [m/s]'),
    ('delay_ms', 'detection delay, median [ms]'),
    ('peak_femur_torque_nm', 'peak femur torque at contact [N m]'),
)


class SweepError(ValueError):
    """A sweep value that cannot be used (the message names the parameter and the value)."""


def sweepable() -> dict[str, ParamSpec]:
    """Sweepable TrialConfig fields -> their declaration (type, range, choices)."""
    return {name: spec for name, spec in specs(TrialConfig).items() if name not in NOT_SWEPT}


def parse_value(param: str, text: str):
    """One command-line value of ``param`` as the TrialConfig field holds it, of the field's declared
    type; SweepError names a bad one (the range is checked with the whole config, :func:`check_config`)."""
    spec = sweepable()[param]
    if spec.type is list:                       # overlays: a tuple of paths
        return () if text.lower() == 'none' else tuple(p for p in text.split(',') if p)
    if spec.optional and text.lower() == 'none':
        return None
    if spec.type is bool:
        if text.lower() not in ('true', 'false', '1', '0'):
            raise SweepError(f'{param}: expected true or false, got {text!r}')
        return text.lower() in ('true', '1')
    if spec.type in (float, int):
        try:
            v = float(text)
        except ValueError:
            raise SweepError(f'{param}: expected a number, got {text!r}') from None
        if not math.isfinite(v):
            raise SweepError(f'{param}: expected a finite number, got {text!r}')
        if spec.type is int:
            if v != int(v):
                raise SweepError(f'{param}: expected a whole number, got {text!r}')
            return int(v)
        return v
    return text


def check_config(cfg: TrialConfig) -> None:
    """Check a config against the settings' declarations and build what a trial builds from it, without
    walking: a bad value fails here, named."""
    from hexapod_locomotion.core.gait import get_gait
    from hexapod_locomotion.core.locomotion_params import LocomotionError
    from hexapod_locomotion.trials.trial_runner import detector_config, locomotion_params
    from hexapod_model.description import load_robot
    try:
        validate(cfg)
    except ParameterError as exc:
        raise SweepError(f'{exc.name}: {exc.reason}') from None
    for p in cfg.overlays:
        if not Path(p).is_file():
            raise SweepError(f'overlays: no such overlay file {p!r}')
    try:
        load_robot(overlays=cfg.overlays)
        get_gait(cfg.gait)
        locomotion_params(cfg)
        detector_config(cfg)
    except (ValueError, LocomotionError) as exc:
        raise SweepError(str(exc).splitlines()[0]) from None


def sweep_configs(base: TrialConfig, param: str, values: list, trials: int) -> list[TrialConfig]:
    """Trials of every value (in the given order), seeds 0..trials-1 each."""
    return [replace(base, **{param: v}, seed=s) for v in values for s in range(trials)]


def summarize(param: str, values: list, results: list[dict]) -> list[dict]:
    """Per value: means over its trials of the walk's figures (None where no trial had them)."""
    rows = []
    for v in values:
        rs = [r for r in results if _as_value(r['config'][param]) == v]

        def mean(xs):
            xs = [x for x in xs if x is not None and math.isfinite(x)]
            return float(np.mean(xs)) if xs else None
        det = [r['detection'] for r in rs if r['detection']]
        rows.append({
            'value': v, 'trials': len(rs),
            'cot': mean([r['cot']['cot'] for r in rs if r['cot']]),
            'speed_mps': mean([r['cot']['speed_mps'] for r in rs if r['cot']]),
            'distance_m': mean([r['distance_m'] for r in rs]),
            'delay_ms': mean([d['delay_s']['median'] * 1e3 for d in det if d['delay_s']]),
            'peak_femur_torque_nm': mean([d['peak_femur_torque_nm']['median'] for d in det if d['peak_femur_torque_nm']]),
            'premature_stops': sum(d['premature_stops'] for d in det),
            'missed_contacts': sum(d['missed_contacts'] for d in det),
            'falls': sum(bool(r['fell']) for r in rs),
        })
    return rows


def _as_value(v):
    return tuple(v) if isinstance(v, list) else v


def _label(v) -> str:
    if isinstance(v, tuple):
        return '+'.join(Path(p).stem for p in v) or 'none'
    return 'none' if v is None else str(v)


def format_table(param: str, rows: list[dict]) -> str:
    def f(v, fmt):
        return format(v, fmt) if v is not None else '-'
    lines = [f'sweep of {param}',
             f'{"value":>16} {"trials":>6} | {"CoT":>6} {"speed":>6} {"dist m":>6} | {"delay ms":>8} {"torque":>6} | '
             f'{"prem.":>5} {"missed":>6} {"falls":>5}']
    for r in rows:
        lines.append(f'{_label(r["value"]):>16} {r["trials"]:6d} | {f(r["cot"], "6.1f"):>6} {f(r["speed_mps"], "6.3f"):>6} '
                     f'{f(r["distance_m"], "6.2f"):>6} | {f(r["delay_ms"], "8.1f"):>8} '
                     f'{f(r["peak_femur_torque_nm"], "6.2f"):>6} | {r["premature_stops"]:5d} {r["missed_contacts"]:6d} '
                     f'{r["falls"]:5d}')
    return '\n'.join(lines)


def plot(param: str, values: list, results: list[dict], rows: list[dict], path: Path) -> None:
    """One figure: each metric against the value, every trial a dot and the mean a line."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    numeric = all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in values)
    xs = [float(v) for v in values] if numeric else list(range(len(values)))
    fig, axes = plt.subplots(1, len(METRICS), figsize=(4.2 * len(METRICS), 3.6))
    for ax, (key, label) in zip(axes, METRICS):
        for x, v in zip(xs, values):
            pts = [_trial_metric(r, key) for r in results if _as_value(r['config'][param]) == v]
            pts = [p for p in pts if p is not None and math.isfinite(p)]
            ax.plot([x] * len(pts), pts, 'o', color='tab:blue', alpha=0.5, ms=4)
        mx = [(x, r[key]) for x, r in zip(xs, rows) if r[key] is not None]
        if mx:
            ax.plot(*zip(*mx), '-', color='tab:orange', lw=2, label='mean of the trials')
            ax.legend(fontsize='small')
        ax.set_xlabel(param)
        ax.set_ylabel(label)
        if not numeric:
            ax.set_xticks(xs, [_label(v) for v in values], rotation=30)
        ax.grid(alpha=0.3)
    fig.suptitle(f'sweep of {param} ({rows[0]["trials"]} trial(s) per value)')
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def _trial_metric(r: dict, key: str):
    det = r['detection']
    if key in ('cot', 'speed_mps'):
        return r['cot'][key] if r['cot'] else None
    if key == 'delay_ms':
        return det['delay_s']['median'] * 1e3 if det and det['delay_s'] else None
    return det['peak_femur_torque_nm']['median'] if det and det['peak_femur_torque_nm'] else None


def main(argv=None) -> int:
    names = sweepable()
    ap = make_parser('experiment', __doc__)
    ap.prog = f'{ap.prog} sweep'
    ap.add_argument('param', metavar='PARAM', help=f'the trial parameter to sweep, one of: {", ".join(names)}')
    ap.add_argument('values', nargs='+', metavar='VALUE', help='its values, in the order to run and plot them')
    ap.add_argument('--trials', type=positive_int, default=1, help='trials (seeds 0..N-1) per value')
    ap.add_argument('--duration', type=positive_float, default=60.0, help='simulated walking time per trial [s]')
    ap.add_argument('--gait', default='tripod', choices=GAITS, help='gait of the base walk')
    ap.add_argument('--detector', default='adaptive', choices=DETECTORS, help='detector of the base walk')
    ap.add_argument('--t-des', type=positive_float, default=1.0, help='swing-down duration of the base walk [s]')
    ap.add_argument('--terrain', default='mockup', help='terrain of the base walk')
    ap.add_argument('--out', default='out/experiments', type=output_directory, help='folder for the PNG and the JSON (created)')
    ap.add_argument('--json', metavar='FILE', help='JSON results (default: OUT/sweep_<PARAM>.json)')
    add_executor_options(ap)
    add_no_progress_option(ap)
    args = ap.parse_args(argv)
    if args.param not in names:
        ap.error(f'unknown parameter {args.param!r}; sweepable: {", ".join(names)}')
    base = TrialConfig(gait=args.gait, detector=args.detector, t_des_s=args.t_des, terrain=args.terrain,
                       duration_s=args.duration, course_end_m=MOCKUP_COURSE_END_M)
    try:
        values = [parse_value(args.param, v) for v in args.values]
        if len(set(values)) != len(values):
            raise SweepError(f'{args.param}: a value is given twice ({" ".join(args.values)})')
        for v in values:
            check_config(replace(base, **{args.param: v}))
    except SweepError as exc:
        ap.error(str(exc))
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        ap.error(f'--out {out} exists and is not a directory')
    cfgs = sweep_configs(base, args.param, values, args.trials)
    try:
        results = map_jobs(trial_job, cfgs, jobs=args.jobs, ray_address=args.ray, desc=f'sweep {args.param}',
                           unit='trial', progress=args.progress)
    except ExecutorError as exc:
        print(f'{ap.prog}: error: {exc}', file=sys.stderr)
        return 1
    except JobsInterrupted as exc:
        if not exc.finished:
            return interrupted(ap.prog, 'no trial had finished, nothing written')
        path = Path(args.json) if args.json else out / f'sweep_{args.param}.json'
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps({'which': 'sweep', 'param': args.param, 'values': values, 'trials': args.trials,
                                    'interrupted': True, 'finished': exc.finished, 'of': len(cfgs),
                                    'trials_results': [{k: v for k, v in r.items() if k != 'events'}
                                                       for r in exc.finished_results()]}, indent=1))
        return interrupted(ap.prog, f'kept {exc.finished} of {len(cfgs)} finished trial(s) in {path}')
    rows = summarize(args.param, values, results)
    print(format_table(args.param, rows))
    out.mkdir(parents=True, exist_ok=True)
    png = out / f'sweep_{args.param}.png'
    plot(args.param, values, results, rows, png)
    path = Path(args.json) if args.json else out / f'sweep_{args.param}.json'
    report = {'which': 'sweep', 'param': args.param, 'values': values, 'trials': args.trials,
              'base': {k: v for k, v in base.__dict__.items() if k != args.param},
              'summary': rows, 'trials_results': [{k: v for k, v in r.items() if k != 'events'} for r in results]}
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(report, indent=1))
    print(f'plot: {png}\nJSON: {path}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
