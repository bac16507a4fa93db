"""./hexapod demo - the simulated robot walks the terrain mockup with the adaptive controller.

The gait controller drives the MuJoCo hexapod lock-stepped through the servo-bus interface (the
same library the ``locomotion_node`` runs on the robot), records every topic of the recording
contract to a rosbag2 MCAP bag under ``bags/``, and prints distance, speed, cost of transport and
the ground-detection statistics. Deterministic for a seed.
"""
from __future__ import annotations

import json
import sys
import time
from pathlib import Path

from hexapod_locomotion.core.metrics import COT_WINDOW_S
from hexapod_locomotion.trials.trial_runner import TrialConfig, check_video, run_trial
from hexapod_model.cli_common import (
    add_no_progress_option,
    add_overlay_option,
    fail,
    finite_float,
    interrupted,
    make_parser,
    nonnegative_int,
    output_file,
    port_number,
    positive_float,
    positive_float_at_most,
)
from hexapod_sim.physics.terrain import MOCKUP_COURSE_END_M

# The walk's time limit counts from the stand-up; the first swing-down comes within about a second.
STAND_UP_MARGIN_S = 1.0


def summary_lines(res) -> list[str]:
    lines = []
    status = 'reached the end of the course' if res.reached_course_end else (
        'FELL' if res.fell else 'stopped at the time limit')
    distance = res.distance_m if round(res.distance_m, 2) != 0 else 0.0      # never '-0.00 m'
    lines.append(f'walked {distance:.2f} m in {res.sim_time_s:.1f} s of simulated time ({status}), '
                 f'{res.phases} swing-down phases')
    if res.cot:
        lines.append(f'speed {res.cot["speed_mps"]:.3f} m/s, mean power {res.cot["power_w"]:.1f} W, '
                     f'cost of transport {res.cot["cot"]:.1f} (Eq. 18, {res.cot["windows"]} windows of 10 s)')
    d = res.detection
    if d:
        lines.append(f'ground detection: {d["swing_downs"]} leg swing-downs, {d["detected"]} contacts detected, '
                     f'{d["premature_stops"]} premature stops, {d["missed_contacts"]} missed contacts, '
                     f'{d["no_ground"]} with no ground in reach')
        if d['delay_control_periods']:
            lines.append(f'  detection delay after true contact: median {d["delay_s"]["median"] * 1e3:.0f} ms '
                         f'({d["delay_control_periods"]["median"]:.1f} control periods), '
                         f'p90 {d["delay_s"]["p90"] * 1e3:.0f} ms')
            lines.append(f'  femur torque at detection: median {d["femur_torque_at_stop_nm"]["median"]:.2f} N m, '
                         f'peak during contact median {d["peak_femur_torque_nm"]["median"]:.2f} N m')
    if res.temperature_femur_c:
        lines.append(f'servo temperature: femur {res.temperature_femur_c[0]:.1f} -> {res.temperature_femur_c[-1]:.1f} C, '
                     f'tibia {res.temperature_tibia_c[0]:.1f} -> {res.temperature_tibia_c[-1]:.1f} C (mean of six)')
    return lines


def build_parser():
    from hexapod_locomotion.core.detector import DETECTOR_KINDS
    from hexapod_locomotion.core.gait import load_gaits
    from hexapod_locomotion.core.locomotion_params import MAX_STEP_S
    from hexapod_sim.node.live import DEFAULT_PORT as DEFAULT_LIVE_PORT
    from hexapod_sim.physics.terrain import MOCKUP_BLOCKS_X_M, MOCKUP_STAIRS_X_M, TERRAINS
    from hexapod_sim.tools.render import VIDEO_EXTENSIONS
    ap = make_parser('demo', __doc__)
    ap.add_argument('--gait', default='tripod', choices=sorted(load_gaits()), help='gait (data/gaits.yaml)')
    ap.add_argument('--detector', default='adaptive', choices=DETECTOR_KINDS, help='ground detector')
    ap.add_argument('--t-des', type=positive_float_at_most(MAX_STEP_S), default=1.0,
                    help=f'swing-down duration t_des [s], at most {MAX_STEP_S:g}')
    ap.add_argument('--terrain', default='mockup', choices=list(TERRAINS), help='terrain')
    ap.add_argument('--seed', type=nonnegative_int, default=0, help='seed of the random terrain parts')
    ap.add_argument('--start-x', type=finite_float, default=0.0,
                    help=f'start position along the course [m]; on the mockup the blocks begin at '
                         f'{MOCKUP_BLOCKS_X_M[0]:g} m and the stairs at {MOCKUP_STAIRS_X_M:g} m, so a short demo '
                         f'starts near them (e.g. --start-x 1.25 --duration 25)')
    ap.add_argument('--duration', type=positive_float, default=180.0,
                    help='simulated walking time limit [s]; checked every control period, so the walk stops '
                         'within one control period (t_con) of it, mid-phase if need be')
    ap.add_argument('--course-end', type=finite_float, default=MOCKUP_COURSE_END_M,
                    help='stop when the trunk passes this x [m]')
    ap.add_argument('--record', default='auto',
                    help="bag directory; 'auto' = bags/demo_<UTC time>; '' = do not record")
    ap.add_argument('--foxglove', metavar='PORT', nargs='?', type=port_number, const=DEFAULT_LIVE_PORT,
                    help=f'serve the walk live to the Foxglove app on ws://127.0.0.1:PORT (default '
                         f'{DEFAULT_LIVE_PORT}): robot model, TF, joint states, ground detection; paces the '
                         f'simulation to real time')
    add_overlay_option(ap)
    ap.add_argument('--json', metavar='FILE', type=output_file(('.json',)), help='also write the full results as JSON')
    ap.add_argument('--video', metavar='GIF', type=output_file(VIDEO_EXTENSIONS),
                    help='also render an animated GIF of the walk (offscreen, CPU)')
    ap.add_argument('--clock-file', metavar='PATH',
                    help='keep the sim time reached in PATH (8 bytes, float64; hexapod_sim.bagio.clock_file): '
                         'the clock by which bench_kills measures what a kill of the demo lost')
    add_no_progress_option(ap)
    return ap


def _checked_outputs(ap, args):
    """Everything the run needs, checked before anything (the bag directory) is created: the course,
    the robot description, the bag's place and the live view. Returns ``(bag directory or None,
    live view or None)``; a problem ends the program with one line."""
    if args.course_end <= args.start_x:
        fail(ap, f'--course-end {args.course_end} must lie beyond --start-x {args.start_x}')
    if args.video:
        from hexapod_sim.tools.render import RenderError
        try:
            check_video(TrialConfig(duration_s=args.duration, video=args.video))
        except RenderError as exc:
            fail(ap, str(exc))
    from hexapod_model.description import DescriptionError, load_robot
    try:
        load_robot(overlays=args.overlay)
    except DescriptionError as exc:
        fail(ap, str(exc))
    from hexapod_sim.bagio.recorder import RecorderError, check_bag_dir, resolve_bag_dir
    bag = None
    if args.record:
        try:
            bag = str(check_bag_dir(resolve_bag_dir(args.record, prefix='demo')))
        except RecorderError as exc:
            fail(ap, str(exc))
    live = None
    if args.foxglove is not None:
        from hexapod_sim.node.live import LiveView, LiveViewError
        try:
            live = LiveView(args.foxglove, name='hexapod demo')
        except LiveViewError as exc:
            fail(ap, str(exc))
    if bag:          # the last check: a place that looks writable may still refuse (root under /proc)
        try:
            Path(bag).mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            if live is not None:
                live.close()
            fail(ap, f'{bag}: cannot create the bag directory: {exc.strerror or exc}')
    return bag, live


def _announce(args, cfg: TrialConfig) -> None:
    """What the demo runs, and a note when the walk is too short for the cost of transport."""
    print(f'hexapod demo: {cfg.gait} gait, {cfg.detector} ground detection, t_des={cfg.t_des_s} s, '
          f'terrain "{cfg.terrain}" (seed {cfg.seed}), simulated AX-12A bus with T_com='
          f'{cfg.t_com_s or "description default"}', flush=True)
    if args.duration < COT_WINDOW_S + STAND_UP_MARGIN_S:
        print(f'note: the cost of transport (Eq. 18) needs {COT_WINDOW_S:g} s of walking from the first swing-down; '
              f'--duration {args.duration:g} leaves less, so it will not be computed (use --duration '
              f'{COT_WINDOW_S + STAND_UP_MARGIN_S:g} or more)', flush=True)


def _interrupted(ap, bag: str | None, video: str | None) -> int:
    """Ctrl-C during the walk (the trial closed its bag and wrote the GIF so far on the way out): an
    empty bag folder is removed, and the line says what was kept."""
    if bag and Path(bag).is_dir() and not any(Path(bag).iterdir()):
        Path(bag).rmdir()         # stopped before the recording began: no empty bag folder left
        bag = None
    kept = [f'bag {bag} closed' if bag else '', f'video {video}' if video and Path(video).is_file() else '']
    kept = [k for k in kept if k]
    return interrupted(ap.prog, f'{" and ".join(kept)}, with the walk so far' if kept else 'nothing recorded')


def _print_results(args, res, bag: str | None) -> None:
    """The summary, the trial's first notes, where the bag and the video are, and the JSON file."""
    for line in summary_lines(res):
        print(line)
    for w in res.warnings[:5]:
        print(f'  note: {w}')
    if len(res.warnings) > 5:
        print(f'  ... {len(res.warnings) - 5} more notes in the JSON output')
    if bag:
        print(f'recorded bag: {bag}  (replay: ./hexapod replay {bag}; analyse: ./hexapod analyse {bag})')
    if args.video:
        print(f'video: {args.video}')
    if args.json:
        with open(args.json, 'w') as f:
            json.dump(res.to_dict(), f, indent=1)
        print(f'results written to {args.json}')


def main(argv=None) -> int:
    ap = build_parser()
    args = ap.parse_args(argv)
    bag, live = _checked_outputs(ap, args)
    if live is not None:
        print(f'live view: {live.url} (Foxglove app: Open connection -> Foxglove WebSocket)', flush=True)
    cfg = TrialConfig(gait=args.gait, detector=args.detector, t_des_s=args.t_des, terrain=args.terrain,
                      seed=args.seed, duration_s=args.duration, course_end_m=args.course_end, record=bag,
                      start_x_m=args.start_x, video=args.video, overlays=tuple(args.overlay))
    _announce(args, cfg)
    from tqdm import tqdm
    total = round(max(args.course_end - args.start_x, 0.01), 2)
    bar = tqdm(total=total, unit='m', desc='walking', file=sys.stderr, mininterval=1.0, disable=not args.progress,
               bar_format='{desc}: {percentage:3.0f}%|{bar}| {n:.2f}/{total:.2f} m [{elapsed}{postfix}]')
    t0 = time.monotonic()

    def progress(t_sim, dist):
        bar.n = round(max(0.0, min(dist, total)), 2)
        bar.set_postfix_str(f'sim {t_sim:.0f} s')

    def on_video(n_frames):          # the walk is over: the bar ends, and the pause that follows is explained
        bar.close()
        print(f'writing GIF {args.video} ({n_frames} frames)...', file=sys.stderr, flush=True)

    clock = None
    if args.clock_file:
        from hexapod_sim.bagio.clock_file import ClockFile
        try:
            clock = ClockFile(args.clock_file)
        except OSError as exc:
            ap.error(f'--clock-file {args.clock_file}: {exc.strerror or exc}')
    try:
        res = run_trial(cfg, progress=progress, on_video_write=on_video, live=live, clock=clock)
    except KeyboardInterrupt:         # the trial closed its bag (and wrote the GIF so far) on the way out
        bar.close()
        return _interrupted(ap, bag, args.video)
    finally:
        if live is not None:
            live.close()
    bar.close()
    print(f'done in {time.monotonic() - t0:.0f} s of wall time')
    _print_results(args, res, bag)
    return 1 if res.fell else 0


if __name__ == '__main__':
    sys.exit(main())
