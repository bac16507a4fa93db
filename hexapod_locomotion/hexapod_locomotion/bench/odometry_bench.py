"""odometry_bench: leg-odometry drift and straight-walk course errors against the simulator's truth.

Walks simulated trials (lock-stepped, no ROS) straight ahead for every gait x terrain x seed, with
the course correction off (the paper's open loop and swing) and, with ``--correction both``, on (as
locomotion_node walks by default: the correction and the obstacle reflex of a swinging leg; with
``--support-margin`` also locomotion_node's support_margin_m). Each trial
runs two leg odometries side by side (with and without /imu). Prints per cell the median and worst
odometry position error in % of the distance walked and yaw error in degrees per metre at the end,
and the walk's own heading change [deg] and distance from the start line [cm] (truth), both as
means over the last gait cycle (a gait sways the body within each cycle: the pentapod on the blocks
+-4 degrees). With ``--distance`` a trial ends once the trunk is that far along x from its start
(``--duration`` is then the time limit). Below the table, per cell, the legs-only odometry's worst walk:
its yaw error and how much of it built up while a foot the odometry took as on the ground was off it
in the simulation, and how often that was so (the median over the cell's walks); and the walk that
ended farthest from its line, with where the odometry put it and how far the feet it stood on moved
in the world (slid, or off the ground): a leg odometry takes them as fixed, so their motion is its error.

    ./hexapod run hexapod_locomotion odometry_bench --terrains flat blocks --seeds 3 --distance 2 --duration 150
"""
from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

from hexapod_locomotion.trials.trial_config import add_support_margin_option
from hexapod_model.cli_common import make_parser, positive_float, positive_int

GAITS = ('tripod', 'tetrapod', 'pentapod')


def build_parser():
    from hexapod_locomotion.trials.executor import add_executor_options
    ap = make_parser('odometry_bench', __doc__)
    ap.add_argument('--gaits', nargs='+', default=list(GAITS), choices=GAITS, metavar='GAIT')
    ap.add_argument('--terrains', nargs='+', default=['flat', 'blocks'], metavar='TERRAIN',
                    help='terrains (hexapod_sim.physics.terrain: flat, blocks, stairs, rough, mockup)')
    ap.add_argument('--seeds', type=positive_int, default=3, metavar='N', help='trials per cell (seeds 0..N-1)')
    ap.add_argument('--duration', type=positive_float, default=40.0, metavar='S',
                    help='simulated walking time (with --distance: its limit)')
    ap.add_argument('--distance', type=positive_float, metavar='M',
                    help='end a straight walk once the trunk is M metres along x from its start')
    ap.add_argument('--correction', choices=('off', 'on', 'both'), default='both',
                    help='on: as locomotion_node walks by default, the heading/lateral correction from the odometry '
                         'and the obstacle reflex of a swinging leg; off: the paper\'s open loop and swing')
    add_support_margin_option(ap, 'the corrected walks')
    ap.add_argument('--turn', type=positive_float, metavar='WZ',
                    help='instead: turn in place at WZ rad/s and print the truth\'s mean yaw rate against it')
    ap.add_argument('--json', metavar='FILE', help='write every trial\'s figures to FILE')
    add_executor_options(ap)
    return ap


def _job(cfg) -> dict:
    """One trial's figures (a process of its own with --jobs)."""
    from hexapod_locomotion.trials.trial_runner import run_trial
    r = run_trial(cfg)
    return {'seed': cfg.seed, 'fell': r.fell, 'distance_m': r.distance_m, 'odometry': r.odometry}


def _row(label: str, trials: list[dict]) -> str:
    def stat(key, odo, scale=1.0):
        v = np.array([t['odometry'][odo][key] for t in trials]) * scale
        return f'{np.median(v):6.2f} {np.max(np.abs(v)):6.2f}'
    head = np.array([abs(t['odometry']['imu']['heading_cycle_mean_deg']) for t in trials])
    line = np.array([abs(t['odometry']['imu']['line_cycle_mean_m']) * 100 for t in trials])
    dist = np.median([t['odometry']['imu']['distance_m'] for t in trials])
    return (f'{label:32s} {len(trials):2d} {dist:5.2f}  {stat("position_error_pct", "imu")}  '
            f'{stat("yaw_error_deg_per_m", "imu")}  {stat("position_error_pct", "legs")}  '
            f'{stat("yaw_error_deg_per_m", "legs")}  {np.median(head):5.2f} {head.max():5.2f}  '
            f'{np.median(line):5.2f} {line.max():5.2f}')


def _off_ground_row(label: str, trials: list[dict]) -> str:
    """The legs-only odometry's worst walk of a cell (by position error): its yaw error, the part built up
    while a foot it used was off the ground (truth), and the cell's median share of such updates."""
    legs = [t['odometry']['legs'] for t in trials]
    worst = max(range(len(legs)), key=lambda i: legs[i]['position_error_pct'])
    w = legs[worst]
    off, rest = w['yaw_error_off_ground_deg'], w['yaw_error_elsewhere_deg']
    share = np.median([o['off_ground_share'] for o in legs]) * 100
    return (f'{label:32s} worst seed {trials[worst]["seed"]}: {w["position_error_pct"]:5.1f} %, yaw error '
            f'{off + rest:+6.1f} deg, {off:+6.1f} of it while a foot it used was off the ground '
            f'({share:4.1f} % of updates, median)')


def _line_row(label: str, trials: list[dict]) -> str:
    """The walk of a cell that ended farthest from its line (truth): where the odometry the correction
    follows (with the IMU) put it, and how far the feet it took as standing moved across the line and
    along it in the world meanwhile (truth)."""
    imu = [t['odometry']['imu'] for t in trials]
    worst = max(range(len(imu)), key=lambda i: abs(imu[i]['line_cycle_mean_m']))
    w = imu[worst]
    return (f'{label:32s} worst seed {trials[worst]["seed"]}: {100 * w["line_cycle_mean_m"]:+5.1f} cm off the line, '
            f'the odometry saw {100 * w["odometry_line_cycle_mean_m"]:+5.1f}; the feet it stood on moved '
            f'{100 * w["feet_moved_across_m"]:+5.1f} cm across, {100 * w["feet_moved_along_m"]:+5.1f} along')


def _cells(args, TrialConfig) -> list[tuple[str, object]]:
    """(cell key, trial config) of every trial to run."""
    from hexapod_locomotion.core.locomotion_params import LocomotionParams
    corrections = {'off': (False,), 'on': (True,), 'both': (False, True)}[args.correction]
    node = LocomotionParams()
    out = []
    for t in args.terrains:
        for g in args.gaits:
            for c in corrections:
                key = f'{g}/{t}/{"on" if c else "off"}'
                for seed in range(args.seeds):
                    walk = dict(gait=g, terrain=t, seed=seed, duration_s=args.duration, heading_correction=c,
                                obstacle_lift_m=node.obstacle_lift_m if c else 0.0,
                                support_margin_m=args.support_margin if c else 0.0)
                    if args.turn:
                        cfg = TrialConfig(**walk, vx_mps=0.0, wz_rad_s=args.turn)
                    else:
                        cfg = TrialConfig(**walk, course_end_m=args.distance)
                    out.append((key, cfg))
    return out


def _print_turn(args, results: dict) -> dict:
    print(f'{"gait/terrain/correction":32s}  n  commanded  truth rad/s (median, worst % off)')
    out = {}
    for key, trials in results.items():
        rates = [np.radians(o['heading_change_deg']) / o['duration_s'] for o in
                 (t['odometry']['imu'] for t in trials if t['odometry']) if o['duration_s'] > 0]
        out[key] = rates
        if rates:
            off = 100 * np.abs(np.array(rates) / args.turn - 1)
            print(f'{key:32s} {len(rates):2d}  {args.turn:9.3f}  {np.median(rates):.4f}  {off.max():5.1f} %')
    return out


def main(argv=None) -> int:
    args = build_parser().parse_args(sys.argv[1:] if argv is None else argv)
    from hexapod_sim.physics.terrain import TERRAINS
    bad = [t for t in args.terrains if t not in TERRAINS]
    if bad:
        print(f'odometry_bench: unknown terrain {bad[0]}; known: {", ".join(TERRAINS)}', file=sys.stderr)
        return 2
    from hexapod_locomotion.trials.executor import ExecutorError, JobsInterrupted, map_jobs
    from hexapod_locomotion.trials.trial_runner import TrialConfig
    cells = _cells(args, TrialConfig)
    try:
        done = map_jobs(_job, [cfg for _, cfg in cells], jobs=args.jobs, ray_address=args.ray, desc='odometry_bench',
                        unit='trial')
    except JobsInterrupted:
        print('odometry_bench: interrupted', file=sys.stderr)
        return 130
    except ExecutorError as exc:
        print(f'odometry_bench: {exc}', file=sys.stderr)
        return 1
    results: dict = {}
    for (key, _), r in zip(cells, done):
        results.setdefault(key, [])
        if r['odometry'] is None or r['fell']:
            print(f'{key} seed {r["seed"]}: no figures ({"fell" if r["fell"] else "no walk"})', file=sys.stderr)
        else:
            results[key].append(r)
    if args.turn:
        out = _print_turn(args, results)
    else:
        out = results
        print(f'{"gait/terrain/correction":32s}  n  dist  pos%imu med/max  deg/m imu     pos% legs     deg/m legs  '
              f'heading deg  line cm (med/max)')
        for key, trials in results.items():
            if trials:
                print(_row(key, trials))
        print('legs only, against the sim\'s foot contacts:')
        for key, trials in results.items():
            if trials:
                print(_off_ground_row(key, trials))
        print('the line, against the odometry and the motion of the feet it stood on (truth):')
        for key, trials in results.items():
            if trials:
                print(_line_row(key, trials))
    if args.json:
        Path(args.json).write_text(json.dumps(out, indent=1))
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
