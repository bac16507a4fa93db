"""odometry_bench: leg-odometry drift and straight-walk course errors against the simulator's truth.

Walks simulated trials (lock-stepped, no ROS) straight ahead for every gait x terrain x seed, with
the course correction off (the paper's open loop) and, with ``--correction both``, on. Each trial
runs two leg odometries side by side (with and without /imu). Prints per cell the median and worst
odometry position error in % of the distance walked and yaw error in degrees per metre at the end,
and the walk's own heading change [deg] and distance from the start line [cm] (truth), both as
means over the last gait cycle (a gait sways the body within each cycle: the pentapod on the blocks
+-4 degrees).

    ./hexapod run hexapod_locomotion odometry_bench --terrains flat blocks --seeds 3 --duration 40
"""
from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

from hexapod_model.cli_common import make_parser, positive_float

GAITS = ('tripod', 'tetrapod', 'pentapod')


def build_parser():
    ap = make_parser('odometry_bench', __doc__)
    ap.add_argument('--gaits', nargs='+', default=list(GAITS), choices=GAITS, metavar='GAIT')
    ap.add_argument('--terrains', nargs='+', default=['flat', 'blocks'], metavar='TERRAIN',
                    help='terrains (hexapod_sim.physics.terrain: flat, blocks, stairs, rough, mockup)')
    ap.add_argument('--seeds', type=int, default=3, metavar='N', help='trials per cell (seeds 0..N-1)')
    ap.add_argument('--duration', type=positive_float, default=40.0, metavar='S', help='simulated walking time')
    ap.add_argument('--correction', choices=('off', 'on', 'both'), default='both',
                    help='heading/lateral correction from odometry (off = the paper\'s open loop)')
    ap.add_argument('--turn', type=positive_float, metavar='WZ',
                    help='instead: turn in place at WZ rad/s and print the truth\'s mean yaw rate against it')
    ap.add_argument('--json', metavar='FILE', help='write every trial\'s figures to FILE')
    return ap


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


def _turn(args, TrialConfig, run_trial) -> int:
    corrections = {'off': (False,), 'on': (True,), 'both': (False, True)}[args.correction]
    print(f'{"gait/terrain/correction":32s}  n  commanded  truth rad/s (median, worst % off)', flush=True)
    out = {}
    for t in args.terrains:
        for g in args.gaits:
            for c in corrections:
                rates = []
                for seed in range(args.seeds):
                    print(f'{g} on {t}, seed {seed}, turning, correction {"on" if c else "off"}', file=sys.stderr, flush=True)
                    r = run_trial(TrialConfig(gait=g, terrain=t, seed=seed, duration_s=args.duration, vx_mps=0.0,
                                              wz_rad_s=args.turn, heading_correction=c))
                    o = r.odometry['imu'] if r.odometry else None
                    if o is not None and o['duration_s'] > 0:
                        rates.append(np.radians(o['heading_change_deg']) / o['duration_s'])
                key = f'{g}/{t}/{"on" if c else "off"}'
                out[key] = rates
                if rates:
                    off = 100 * np.abs(np.array(rates) / args.turn - 1)
                    print(f'{key:32s} {len(rates):2d}  {args.turn:9.3f}  {np.median(rates):.4f}  {off.max():5.1f} %', flush=True)
    if args.json:
        Path(args.json).write_text(json.dumps(out, indent=1))
    return 0


def main(argv=None) -> int:
    args = build_parser().parse_args(sys.argv[1:] if argv is None else argv)
    from hexapod_sim.physics.terrain import TERRAINS
    bad = [t for t in args.terrains if t not in TERRAINS]
    if bad or args.seeds < 1:
        print(f'odometry_bench: {"unknown terrain " + bad[0] + "; known: " + ", ".join(TERRAINS) if bad else "--seeds must be >= 1"}',
              file=sys.stderr)
        return 2
    from hexapod_locomotion.trials.trial_runner import TrialConfig, run_trial
    if args.turn:
        return _turn(args, TrialConfig, run_trial)
    corrections = {'off': (False,), 'on': (True,), 'both': (False, True)}[args.correction]
    cells = [(g, t, c) for t in args.terrains for g in args.gaits for c in corrections]
    results: dict = {}
    n, total = 0, len(cells) * args.seeds
    for g, t, c in cells:
        trials = []
        for seed in range(args.seeds):
            n += 1
            print(f'[{n}/{total}] {g} on {t}, seed {seed}, correction {"on" if c else "off"}', file=sys.stderr, flush=True)
            r = run_trial(TrialConfig(gait=g, terrain=t, seed=seed, duration_s=args.duration, heading_correction=c))
            if r.odometry is None or r.fell:
                print(f'  no figures: {"fell" if r.fell else "no walk"}', file=sys.stderr)
                continue
            trials.append({'seed': seed, 'fell': r.fell, 'distance_m': r.distance_m, 'odometry': r.odometry})
        results[f'{g}/{t}/{"on" if c else "off"}'] = trials
    print(f'{"gait/terrain/correction":32s}  n  dist  pos%imu med/max  deg/m imu     pos% legs     deg/m legs  '
          f'heading deg  line cm (med/max)')
    for key, trials in results.items():
        if trials:
            print(_row(key, trials))
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=1))
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
