"""./hexapod experiment - the paper's evaluation (Sec. 8) reproduced in simulation.

Sub-commands (each deterministic for its seeds, lock-stepped, trials in parallel processes):

* ``table4``  cost of transport and speed for {tripod, tetrapod, pentapod} x t_des {0.5, 1} s x
  {fixed, adaptive, improved}, several trials each on the mockup, printed beside the paper's Table 4
  (adaptive = the paper's Algorithm 1, the reference; improved = the same detector with the approach
  goal profile, ``--approach-rate``, and an 80 ms dwell at theta_fin with a 1-tick Eq. 17 margin), with
  body rise and detection delay beyond the floor per cell;
* ``fig11``   per-leg variance of pitch, roll and vertical acceleration during swing-down (box plots);
* ``fig12``   servo temperature over a long tripod walk, fixed vs adaptive;
* ``quality`` ground-detection quality: free swing on a stand at t_des {0.5, 1, 2} s (premature
  stops) and, on the mockup, delay from true contact, torque at detection, premature/missed stops;
* ``all``     everything above into one JSON and the PNGs;
* ``sweep``   one trial parameter over a list of values (``./hexapod experiment sweep --help``,
  :mod:`hexapod_locomotion.trials.sweep`).

Trials run in local processes (``--jobs``) or as Ray tasks (``--ray [ADDRESS]``,
:mod:`hexapod_locomotion.trials.executor`); the results are the same.
"""
from __future__ import annotations

import json
import math
import sys
from pathlib import Path

import numpy as np

from hexapod_locomotion.core.locomotion_params import LocomotionParams
from hexapod_locomotion.trials.executor import ExecutorError, JobsInterrupted, add_executor_options, map_jobs
from hexapod_locomotion.trials.trial_config import add_support_margin_option
from hexapod_locomotion.trials.trial_runner import (
    GAITS,
    TrialConfig,
    detector_config,
    locomotion_params,
    trial_job,
)
from hexapod_model.cli_common import (
    add_no_progress_option,
    interrupted,
    make_parser,
    output_directory,
    positive_float,
    positive_int,
)
from hexapod_sim.physics.terrain import MOCKUP_COURSE_END_M

# Every table has three cells per gait x t_des: the fixed-threshold baseline, the paper's Algorithm 1
# (Eq. 15 goals, Eq. 17 threshold: the reference) and the improved touchdown (the same detector with
# the approach goal profile, LocomotionParams.approach_rate; --approach-rate).
VARIANTS = ('fixed', 'adaptive', 'improved')
IMPROVED_APPROACH_RATE = 0.5
# The improved touchdown's dwell at theta_fin and the Eq. 17 margin in it (DetectorConfig.dwell_epsilon_tick).
# Measured with table4 on the mockup, 10 trials of 60 s per cell: 50 ms with Eq. 17's 3 ticks missed 0.7-2.1 % of
# the contacts per cell; with 1 tick 0.2-1.5 % (tripod t_des 1 s: 16 of 1080); 80 ms with 1 tick
# 0.2-0.9 % (tripod 1 s: 9 of 1089). 0.5 ticks in 50 ms missed 6 of 1086 there but stopped more free legs
# at theta_fin (12 against 9 premature stops): too close to the servo's one-tick resolution.
IMPROVED_FIN_DWELL_S = 0.08
IMPROVED_DWELL_EPSILON_TICK = 1.0
APPROACH = {'rate': IMPROVED_APPROACH_RATE}      # --approach-rate


def variant(cfg: dict) -> str:
    """The table cell of a trial config (as dict): 'fixed', 'adaptive' (paper) or 'improved'."""
    if cfg['detector'] == 'adaptive' and cfg.get('approach_rate', 1.0) < 1.0:
        return 'improved'
    return cfg['detector']


def variant_fields(v: str) -> dict:
    """TrialConfig fields of a table cell."""
    if v == 'improved':
        return {'detector': 'adaptive', 'approach_rate': APPROACH['rate'], 'fin_dwell_s': IMPROVED_FIN_DWELL_S,
                'dwell_epsilon_tick': IMPROVED_DWELL_EPSILON_TICK}
    return {'detector': v}
PAPER_TABLE4 = {  # (gait, t_des, detector): (CoT, speed m/s), paper Table 4
    ('tripod', 0.5, 'fixed'): (25.9, 0.044), ('tripod', 0.5, 'adaptive'): (22.0, 0.046),
    ('tripod', 1.0, 'fixed'): (35.4, 0.041), ('tripod', 1.0, 'adaptive'): (16.1, 0.035),
    ('tetrapod', 0.5, 'fixed'): (29.4, 0.034), ('tetrapod', 0.5, 'adaptive'): (32.4, 0.035),
    ('tetrapod', 1.0, 'fixed'): (19.6, 0.029), ('tetrapod', 1.0, 'adaptive'): (19.3, 0.030),
    ('pentapod', 0.5, 'fixed'): (28.5, 0.021), ('pentapod', 0.5, 'adaptive'): (27.4, 0.028),
    ('pentapod', 1.0, 'fixed'): (28.5, 0.019), ('pentapod', 1.0, 'adaptive'): (28.4, 0.017),
}
GAIT_DIGIT = {'tripod': 3, 'tetrapod': 4, 'pentapod': 5}


PROGRESS = {'disable': False}          # --no-progress; bars go to stderr


EXECUTOR = {'ray': None}              # --ray [ADDRESS]: run trials as Ray tasks (None = local processes)


def run_many(configs: list[TrialConfig], jobs: int, desc: str) -> list[dict]:
    """Run trials in parallel (processes, or Ray tasks with ``--ray``) with a progress bar; results in
    the order of ``configs``, the same for the same configs on every executor."""
    try:
        return map_jobs(trial_job, configs, jobs=jobs, ray_address=EXECUTOR['ray'], desc=desc, unit='trial',
                        progress=not PROGRESS['disable'])
    except JobsInterrupted as exc:
        exc.desc = desc              # named in the line that says what was kept
        raise


# ----------------------------------------------------------------------------- Table 4
# The walking command of the mockup trials: above every gait's stride limit (at most 0.063 m/s, tripod
# at t_des 0.5 s), so each gait walks as fast as its cycle and stride allow, as the paper's robot did
# with one parametrization of the gaits. (At 0.05 m/s the tripod at t_des 0.5 s walked the command,
# 0.045 m/s on the mockup, under the paper's 0.046.)
TABLE4_VX_MPS = 0.1


def table4_configs(trials: int, duration_s: float, terrain: str, t_des=(0.5, 1.0),
                   fixed_threshold_tick: float = 21.0, variants=VARIANTS,
                   heading_correction: bool = False, obstacle_reflex: bool = False,
                   support_margin_m: float = 0.0) -> list[TrialConfig]:
    lift = LocomotionParams().obstacle_lift_m if obstacle_reflex else 0.0
    return [TrialConfig(gait=g, t_des_s=t, terrain=terrain, seed=s, duration_s=duration_s, vx_mps=TABLE4_VX_MPS,
                        course_end_m=MOCKUP_COURSE_END_M, fixed_threshold_tick=fixed_threshold_tick,
                        heading_correction=heading_correction, obstacle_lift_m=lift, support_margin_m=support_margin_m,
                        **variant_fields(d))
            for g in GAITS for t in t_des for d in variants for s in range(trials)]


def summarize_table4(results: list[dict]) -> list[dict]:
    rows = []
    for g in GAITS:
        for t in (0.5, 1.0):
            for d in VARIANTS:
                rs = [r for r in results if r['config']['gait'] == g and r['config']['t_des_s'] == t
                      and variant(r['config']) == d]
                if not rs:
                    continue
                det = [r['detection'] for r in rs if r['detection']]
                rise = [x['body_rise_m']['median'] for x in det if x.get('body_rise_m')]
                beyond = [x['delay_beyond_floor_periods']['median'] for x in det if x.get('delay_beyond_floor_periods')]
                swings = sum(x['swing_downs'] for x in det)
                cots = [r['cot']['cot'] for r in rs if r['cot'] and math.isfinite(r['cot']['cot'])]
                speeds = [r['cot']['speed_mps'] for r in rs if r['cot']]
                peak = [r['detection']['peak_femur_torque_nm']['median'] for r in rs
                        if r['detection'] and r['detection']['peak_femur_torque_nm']]
                paper = PAPER_TABLE4[(g, t, 'fixed' if d == 'fixed' else 'adaptive')]
                rows.append({'gait': g, 't_des_s': t, 'detector': d, 'trials': len(rs),
                             'cot': float(np.mean(cots)) if cots else None,
                             'speed_mps': float(np.mean(speeds)) if speeds else None,
                             'falls': sum(r['fell'] for r in rs),
                             'premature_stops': sum(r['detection']['premature_stops'] for r in rs if r['detection']),
                             'missed_contacts': sum(r['detection']['missed_contacts'] for r in rs if r['detection']),
                             'peak_femur_torque_nm': float(np.mean(peak)) if peak else None,
                             'swing_downs': swings,
                             'body_rise_mm': float(np.mean(rise)) * 1e3 if rise else None,
                             'delay_beyond_floor_periods': float(np.mean(beyond)) if beyond else None,
                             'paper_cot': paper[0], 'paper_speed_mps': paper[1],
                             'cot_missing': _cot_missing(rs)})
    return rows


def _cot_missing(results: list[dict]) -> str | None:
    """Why no trial of a cell has a cost of transport (its first trial's reason), or None."""
    if any(r['cot'] for r in results):
        return None
    why = [w.removeprefix('CoT not computed: ') for r in results for w in r.get('warnings', [])
           if w.startswith('CoT not computed: ')]
    return why[0] if why else 'no trial computed it'


def cot_note(rows: list[dict]) -> str | None:
    """One line explaining the cells whose CoT and speed are '-', or None."""
    missing = [r for r in rows if r.get('cot_missing')]
    if not missing:
        return None
    from hexapod_locomotion.core.metrics import COT_WINDOW_S
    return (f'CoT and speed -: {len(missing)} cell(s) without one {COT_WINDOW_S:g} s window of Eq. 18 '
            f'(e.g. {missing[0]["gait"]} {missing[0]["t_des_s"]:g} {missing[0]["detector"]}: {missing[0]["cot_missing"]}); '
            f'give --duration {COT_WINDOW_S + 1:g} or more')


def format_table4(rows: list[dict]) -> str:
    def f(v, fmt):
        return format(v, fmt) if v is not None else '   -'
    lines = ['Table 4 (simulation vs paper): cost of transport and speed',
             f'{"gait":9} {"t_des":>5} {"detection":9} | {"CoT":>6} {"paper":>6} | {"speed":>6} {"paper":>6} | '
             f'{"falls":>5} {"prem.":>5} {"missed":>6} {"torque":>6} {"rise":>5} {"beyond":>6}']
    for r in rows:
        lines.append(f'{r["gait"]:9} {r["t_des_s"]:5.1f} {r["detector"]:9} | {f(r["cot"], "6.1f")} {r["paper_cot"]:6.1f} | '
                     f'{f(r["speed_mps"], "6.3f")} {r["paper_speed_mps"]:6.3f} | {r["falls"]:5d} {r["premature_stops"]:5d} '
                     f'{r["missed_contacts"]:6d} {f(r["peak_femur_torque_nm"], "6.2f")} {f(r["body_rise_mm"], "5.1f")} '
                     f'{f(r["delay_beyond_floor_periods"], "6.1f")}')
    note = cot_note(rows)
    if note:
        lines.append(note)
    for v in ('adaptive', 'improved'):
        wins = 0
        cells = 0
        for g in GAITS:
            for t in (0.5, 1.0):
                a = next((r for r in rows if (r['gait'], r['t_des_s'], r['detector']) == (g, t, v)), None)
                b = next((r for r in rows if (r['gait'], r['t_des_s'], r['detector']) == (g, t, 'fixed')), None)
                if a and b and a['cot'] is not None and b['cot'] is not None:
                    cells += 1
                    wins += a['cot'] < b['cot']
        if cells:
            lines.append(f'{v} has a lower CoT than fixed in {wins} of {cells} gait x t_des cells'
                         + (' (paper: 5 of 6)' if v == 'adaptive' else ''))
    lines.append('adaptive = the paper\'s Algorithm 1; improved = the same with the approach goal profile (paper '
                 'columns: adaptive); torque = median peak femur torque during contact [N m]; rise = median body '
                 'rise during a swing-down [mm] (truth); beyond = median detection delay beyond the blocked-leg '
                 'floor [control periods]')
    return '\n'.join(lines)


# ----------------------------------------------------------------------------- Fig. 11
def plot_fig11(results: list[dict], path: Path) -> None:
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    labels, data = [], {'var_pitch': [], 'var_roll': [], 'var_acc_z': []}
    for g in GAITS:
        for d in VARIANTS:
            rs = [r for r in results if r['config']['gait'] == g and variant(r['config']) == d
                  and r['config']['t_des_s'] == 1.0]
            if not rs:
                continue
            labels.append(f'{GAIT_DIGIT[g]}_{ {"adaptive": "adapt", "improved": "impr"}.get(d, d)}')
            for k in data:
                data[k].append([s[k] for r in rs for s in r['stability']] or [np.nan])
    fig, axes = plt.subplots(1, 3, figsize=(15, 4))
    for ax, (k, title) in zip(axes, (('var_pitch', 'pitch variance [rad$^2$]'), ('var_roll', 'roll variance [rad$^2$]'),
                                     ('var_acc_z', 'Acc$_z$ variance [(m/s$^2$)$^2$]'))):
        ax.boxplot(data[k], showfliers=False)
        ax.set_xticks(range(1, len(labels) + 1), labels, rotation=45)
        ax.set_yscale('log')
        ax.set_title(title)
    fig.suptitle('Fig. 11 (simulation): body motion during swing-down, t_des = 1 s, per leg')
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def summarize_fig11(results: list[dict]) -> list[dict]:
    out = []
    for g in GAITS:
        for d in VARIANTS:
            st = [s for r in results if r['config']['gait'] == g and variant(r['config']) == d
                  and r['config']['t_des_s'] == 1.0 for s in r['stability']]
            if st:
                out.append({'gait': g, 'detector': d, 'samples': len(st),
                            **{f'median_{k}': float(np.median([s[k] for s in st])) for k in ('var_pitch', 'var_roll', 'var_acc_z')}})
    return out


# ----------------------------------------------------------------------------- Fig. 12
def plot_fig12(results: list[dict], path: Path) -> None:
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(7, 4))
    for r in results:
        d = variant(r['config'])
        t = np.array(r['temperature_t_s']) / 60.0
        ls = {'fixed': '-', 'adaptive': '--'}.get(d, ':')
        ax.plot(t, r['temperature_femur_c'], label=f'{d} femur', ls=ls)
        ax.plot(t, r['temperature_tibia_c'], label=f'{d} tibia', ls=ls, alpha=0.7)
    ax.set_xlabel('time [min]')
    ax.set_ylabel('mean servo temperature [C]')
    ax.set_title('Fig. 12 (simulation): tripod, t_des = 1 s')
    ax.legend()
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


# ----------------------------------------------------------------------------- free swing on a stand
def free_swing_quality(t_des_values=(0.5, 1.0, 2.0), phases_per_gait: int = 6) -> list[dict]:
    """Robot on a stand (no ground): every swing-down must run to theta_fin; a contact stop is premature."""
    from tqdm import tqdm

    from hexapod_locomotion.core.controller import GaitController
    from hexapod_locomotion.core.detector import STOP_CONTACT
    from hexapod_locomotion.core.gait import get_gait
    from hexapod_locomotion.core.locomotion_params import VelocityCommand
    from hexapod_model.description import load_robot
    from hexapod_sim.physics.plant import HexapodSim
    robot = load_robot()
    out = []
    bar = tqdm(total=len(GAITS) * len(t_des_values) * len(VARIANTS), desc='free swing on a stand', unit='cell',
               file=sys.stderr, **PROGRESS)
    for g in GAITS:
        for t in t_des_values:
            for d in VARIANTS:
                bar.update()
                cfg = TrialConfig(gait=g, t_des_s=t, **variant_fields(d))
                sim = HexapodSim(robot, terrain='flat', fixed_base=True)
                c = GaitController(robot, get_gait(g), locomotion_params(cfg), detector_config(cfg), t_com_s=sim.t_com_s)
                c.startup(sim)
                stops = []
                for _ in range(phases_per_gait):
                    rep = c.step_phase(sim, VelocityCommand(0.05, 0.0, 0.0))
                    stops += [o for o in rep.outcomes]
                premature = sum(o.stop_reason == STOP_CONTACT for o in stops)
                out.append({'gait': g, 't_des_s': t, 'detector': d, 'swing_downs': len(stops),
                            'premature_stops': premature,
                            'median_stop_time_s': float(np.median([o.stop_time_s for o in stops]))})
    bar.close()
    return out


def format_free_swing(rows: list[dict]) -> str:
    lines = ['Free swing on a stand (no ground): stops before theta_fin are premature',
             f'{"gait":9} {"t_des":>5} {"detection":9} {"swings":>6} {"premature":>9}']
    for r in rows:
        lines.append(f'{r["gait"]:9} {r["t_des_s"]:5.1f} {r["detector"]:9} {r["swing_downs"]:6d} {r["premature_stops"]:9d}')
    return '\n'.join(lines)


def format_quality(results: list[dict]) -> str:
    lines = ['Ground-detection quality on the mockup (simulation truth)',
             f'{"gait":9} {"t_des":>5} {"detection":9} | {"delay ms":>8} {"periods":>7} {"floor":>5} {"beyond":>6} | '
             f'{"torque@stop":>11} {"peak torque":>11} | {"overshoot mm":>12} {"rise mm":>7} | {"prem.":>5} {"missed":>6}']
    for g in GAITS:
        for t in sorted({r['config']['t_des_s'] for r in results}):
            for d in VARIANTS:
                rs = [r['detection'] for r in results if r['detection'] and (r['config']['gait'], r['config']['t_des_s'],
                                                                             variant(r['config'])) == (g, t, d)]
                if not rs:
                    continue
                detected = sum(x['detected'] for x in rs)
                timed = [x for x in rs if x['delay_s']]
                swings = sum(x.get('swing_downs', 0) for x in rs)
                missed = sum(x['missed_contacts'] for x in rs)
                rises = [x['body_rise_m']['median'] for x in rs if x.get('body_rise_m')]
                rise = f'{np.mean(rises) * 1e3:7.1f}' if rises else f'{"-":>7}'
                tail = (f'{sum(x["premature_stops"] for x in rs):5d} {missed:6d}   ({detected} contacts detected'
                        + (f' in {swings} swing-downs)' if swings else ')'))
                if not timed:       # no contact detected after a true contact: the failing cell, shown
                    lines.append(f'{g:9} {t:5.1f} {d:9} | {"-":>8} {"-":>7} {"-":>5} {"-":>6} | {"-":>11} {"-":>11} | '
                                 f'{"-":>12} {rise} | {tail}')
                    continue
                m = lambda k, s='median': float(np.mean([x[k][s] for x in timed]))  # noqa: E731
                fl = [x['blocked_leg_floor_periods']['median'] for x in timed if x.get('blocked_leg_floor_periods')]
                floor = f'{np.mean(fl):5.1f}' if fl else '    -'
                bf = [x['delay_beyond_floor_periods']['median'] for x in timed if x.get('delay_beyond_floor_periods')]
                beyond = f'{np.mean(bf):6.1f}' if bf else f'{"-":>6}'
                lines.append(f'{g:9} {t:5.1f} {d:9} | {m("delay_s") * 1e3:8.1f} {m("delay_control_periods"):7.1f} {floor} '
                             f'{beyond} | {m("femur_torque_at_stop_nm"):11.2f} {m("peak_femur_torque_nm"):11.2f} | '
                             f'{m("command_overshoot_m") * 1e3:12.1f} {rise} | {tail}')
    lines.append('periods = control periods t_con from the first true contact to the stop; floor = (threshold - error) '
                 'at the first read in contact / femur goal step: the fewest periods in which even a rigidly blocked '
                 'leg crosses the threshold (adaptive: about epsilon / step); beyond = periods - floor; rise = median '
                 'body rise during a swing-down (truth); adaptive = the paper\'s Algorithm 1, improved = with the '
                 'approach goal profile')
    return '\n'.join(lines)


# ----------------------------------------------------------------------------- CLI
def main(argv=None) -> int:
    from hexapod_sim.physics.terrain import TERRAINS
    argv = sys.argv[1:] if argv is None else list(argv)
    if argv[:1] == ['sweep']:
        from hexapod_locomotion.trials.sweep import main as sweep_main
        return sweep_main(argv[1:])
    ap = make_parser('experiment', __doc__)
    ap.add_argument('which', choices=['table4', 'fig11', 'fig12', 'quality', 'all', 'sweep'], help='what to run (see above)')
    ap.add_argument('--trials', type=positive_int, default=3, help='trials per cell (seeds 0..N-1)')
    ap.add_argument('--duration', type=positive_float, default=60.0, help='simulated walking time per trial [s]')
    ap.add_argument('--fig12-duration', type=positive_float, default=600.0, help='simulated time of the Fig. 12 walk [s]')
    ap.add_argument('--terrain', default='mockup', choices=list(TERRAINS), help='terrain of the mockup trials')
    ap.add_argument('--fixed-threshold', type=positive_float, default=21.0,
                    help="threshold of the fixed detector [ticks] (paper: 21, found for the authors' robot)")
    ap.add_argument('--out', default='out/experiments', type=output_directory, help='folder for PNGs and the JSON (created)')
    ap.add_argument('--json', metavar='FILE', help='JSON results (default: OUT/<which>.json)')
    ap.add_argument('--approach-rate', type=positive_float, default=IMPROVED_APPROACH_RATE,
                    help='approach_rate of the improved touchdown cells (fraction of the Eq. 15 goal rate near the '
                         'expected ground, below 1)')
    ap.add_argument('--variants', nargs='+', choices=VARIANTS, default=list(VARIANTS), metavar='VARIANT',
                    help=f'the table cells per gait and t_des to run ({", ".join(VARIANTS)})')
    ap.add_argument('--heading-correction', action='store_true',
                    help="walk with the course correction from the odometry (default: the paper's open loop)")
    ap.add_argument('--obstacle-reflex', action='store_true',
                    help="lift a swinging leg that meets an obstacle higher, as locomotion_node does (default: the "
                         "paper's swing)")
    add_support_margin_option(ap, 'the trials')
    add_executor_options(ap)
    add_no_progress_option(ap)
    args = ap.parse_args(argv)
    if not args.approach_rate < 1.0:
        ap.error(f'--approach-rate must be below 1 (1 is the paper\'s Eq. 15), got {args.approach_rate:g}')
    APPROACH['rate'] = args.approach_rate
    PROGRESS['disable'] = not args.progress
    EXECUTOR['ray'] = args.ray
    if args.which == 'sweep':
        ap.error('sweep takes its own arguments first: ./hexapod experiment sweep PARAM VALUE... [options]')
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        ap.error(f'--out {out} exists and is not a directory')
    report: dict = {'which': args.which, 'trials': args.trials, 'duration_s': args.duration, 'terrain': args.terrain,
                    'fixed_threshold_tick': args.fixed_threshold, 'approach_rate': args.approach_rate,
                    'variants': args.variants, 'heading_correction': args.heading_correction,
                    'obstacle_reflex': args.obstacle_reflex, 'support_margin': args.support_margin}
    try:
        return _run(args, out, report)
    except ExecutorError as exc:
        print(f'{ap.prog}: error: {exc}', file=sys.stderr)
        return 1
    except KeyboardInterrupt as exc:
        return _keep_interrupted(ap.prog, args, out, report, exc)


def _json_path(args, out: Path) -> Path:
    return Path(args.json) if args.json else out / f'{args.which}.json'


def _keep_interrupted(prog: str, args, out: Path, report: dict, exc: KeyboardInterrupt) -> int:
    """Ctrl-C: write what had finished (the stages done and the finished trials of the one under way)
    to the JSON, say so in one line; nothing is written when no trial had finished."""
    partial = exc.finished_results() if isinstance(exc, JobsInterrupted) else []
    stages = [k for k in ('trials_results', 'free_swing', 'fig12') if k in report]
    trials = len(report.get('trials_results', [])) + len(report.get('fig12', [])) + len(partial)
    if not stages and not partial:
        return interrupted(prog, 'no trial had finished, nothing written')
    report['interrupted'] = True
    if partial:
        report['interrupted_stage'] = {'stage': getattr(exc, 'desc', ''), 'finished': len(partial),
                                       'of': len(exc.results)}
        report['interrupted_stage_results'] = [{k: v for k, v in r.items() if k != 'events'} for r in partial]
    path = _json_path(args, out)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(report, indent=1))
    what = f'{trials} finished trial(s)' + (f' ({len(partial)} of {len(exc.results)} {exc.desc})' if partial else '')
    if 'free_swing' in report:
        what += ' and the free-swing table'
    return interrupted(prog, f'kept {what} in {path}')


def _run(args, out: Path, report: dict) -> int:
    if args.which in ('table4', 'fig11', 'quality', 'all'):
        t_des = (1.0,) if args.which == 'fig11' else (0.5, 1.0)
        cfgs = table4_configs(args.trials, args.duration, args.terrain, t_des, args.fixed_threshold,
                              args.variants, args.heading_correction, args.obstacle_reflex, args.support_margin)
        results = run_many(cfgs, args.jobs, 'mockup trials')
        report['trials_results'] = [{k: v for k, v in r.items() if k != 'events'} for r in results]
        if args.which in ('table4', 'all'):
            rows = summarize_table4(results)
            report['table4'] = rows
            print(format_table4(rows))
        if args.which in ('fig11', 'all'):
            out.mkdir(parents=True, exist_ok=True)
            plot_fig11(results, out / 'fig11_stability.png')
            report['fig11'] = summarize_fig11(results)
            print(f'Fig. 11 box plots: {out / "fig11_stability.png"}')
        if args.which in ('quality', 'all'):
            print(format_quality(results))
    if args.which in ('quality', 'all'):
        rows = free_swing_quality()
        report['free_swing'] = rows
        print(format_free_swing(rows))
    if args.which in ('fig12', 'all'):
        cfgs = [TrialConfig(gait='tripod', t_des_s=1.0, terrain='rough', duration_s=args.fig12_duration,
                            wz_rad_s=0.04, probe_period_s=0.5, fixed_threshold_tick=args.fixed_threshold,
                            **variant_fields(d))
                for d in VARIANTS]
        res12 = run_many(cfgs, args.jobs, 'fig12 walks')
        out.mkdir(parents=True, exist_ok=True)
        plot_fig12(res12, out / 'fig12_temperature.png')
        report['fig12'] = [{'detector': variant(r['config']), 'path_length_m': r['path_length_m'], 'fell': r['fell'],
                            'femur_c_start': r['temperature_femur_c'][0], 'femur_c_end': r['temperature_femur_c'][-1],
                            'tibia_c_end': r['temperature_tibia_c'][-1],
                            'temperature_t_s': r['temperature_t_s'], 'femur_c': r['temperature_femur_c'],
                            'tibia_c': r['temperature_tibia_c']} for r in res12]
        for r in report['fig12']:
            print(f'Fig. 12 {r["detector"]:8}: femur {r["femur_c_start"]:.1f} -> {r["femur_c_end"]:.1f} C, '
                  f'tibia -> {r["tibia_c_end"]:.1f} C over {args.fig12_duration / 60:.0f} min, walked {r["path_length_m"]:.2f} m')
        print(f'Fig. 12 plot: {out / "fig12_temperature.png"}')
    path = _json_path(args, out)
    path.parent.mkdir(parents=True, exist_ok=True)      # created when there is something to write
    path.write_text(json.dumps(report, indent=1))
    print(f'JSON: {path}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
