"""Sim-vs-real discrepancy: where the recording departs from the model, and which physics is missing.

Replays the goals recorded in BAG through the nominal model (robot description + servo model),
finds where the recorded reads depart from the prediction, names the missing physical effect
from a library of candidates, fits it, and shows the before/after on held-out data. No ROS graph
is needed (``./hexapod discrepancy`` or ``ros2 run hexapod_sim discrepancy``).
"""
from __future__ import annotations

import json
import sys
import warnings

from hexapod_model.cli_common import (
    add_no_progress_option,
    add_overlay_option,
    existing_file,
    finite_float,
    interrupted,
    make_parser,
    nonnegative_int,
    open_for_writing,
    output_file,
    plot_extensions,
    positive_float,
    positive_or_inf,
    ratio_at_least_one,
)
from hexapod_model.description import ALL_JOINTS, DescriptionError, load_robot
from hexapod_model.joints import Joint
from hexapod_sim.bagio import BagWarning, one_warning
from hexapod_sim.discrepancy.analysis import MODES, analyse
from hexapod_sim.discrepancy.effects import BY_NAME
from hexapod_sim.discrepancy.fit import FitSettings
from hexapod_sim.discrepancy.loaded_search import SEARCH_BUDGET_S
from hexapod_sim.discrepancy.recording import RecordingError, load_recording
from hexapod_sim.discrepancy.segments import parse_windows
from hexapod_sim.physics.terrain import TERRAINS, Ground


def build_parser():
    ap = make_parser('discrepancy', __doc__)
    ap.add_argument('bag', help='rosbag2 directory or .mcap file following the recording contract')
    ap.add_argument('--json', metavar='OUT.json', type=output_file(('.json',), create_parent=True),
                    help='write the machine-readable result here')
    ap.add_argument('--plot', metavar='OUT.png', type=output_file(plot_extensions, create_parent=True),
                    help='write the before/after figure here')
    ap.add_argument('--write-overlay', metavar='OUT.yaml', type=output_file(('.yaml', '.yml'), create_parent=True),
                    help='write the fitted effects as a robot-description overlay (read it back with --overlay)')
    ap.add_argument('--joints', nargs='+', metavar='JOINT', help='analyse only these joints (e.g. leg3_tibia)')
    ap.add_argument('--time', nargs='+', metavar='START:END', dest='windows',
                    help='analyse only these time windows [s from the bag start], in which the legs hang free')
    ap.add_argument('--mode', choices=MODES, default='auto',
                    help='stand: legs free all the time; walk: only swing phases; auto: decide from the data')
    ap.add_argument('--robot', metavar='ROBOT.yaml', type=existing_file,
                    help='robot description (default: the packaged data/robot.yaml)')
    add_overlay_option(ap, 'robot-description overlay applied before the analysis (e.g. a previous '
                           '--write-overlay result); repeatable, applied in order')
    ap.add_argument('--candidates', nargs='+', choices=sorted(BY_NAME), metavar='EFFECT',
                    help=f'test only these effects (default all: {", ".join(BY_NAME)})')
    ap.add_argument('--holdout-block', type=positive_float, default=None, metavar='S',
                    help='length of the alternating fit / held-out time blocks [s] (default: 2 s on a stand, '
                         'alternate swings of each leg on a walk)')
    ap.add_argument('--min-ratio', type=ratio_at_least_one, default=FitSettings.min_ratio,
                    help='held-out RMS improvement factor an effect must reach')
    ap.add_argument('--terrain', choices=(*TERRAINS, 'none'), default=None,
                    help="what a walk was recorded on, for the whole-walk replay on the MuJoCo hexapod (default: "
                         "the bag's /sim/scene, else flat: a calibration walk on a floor); none: no whole-walk replay")
    ap.add_argument('--terrain-seed', type=nonnegative_int, default=0, metavar='N', help='the terrain\'s seed (with --terrain)')
    ap.add_argument('--start-xy', type=finite_float, nargs=2, default=(0.0, 0.0), metavar=('X', 'Y'),
                    help='where the trunk started on the terrain [m] (with --terrain)')
    ap.add_argument('--search-budget', type=positive_or_inf, default=SEARCH_BUDGET_S, metavar='S',
                    help='seconds of walk the whole walk\'s loaded-phase search may replay before it begins no further '
                         f'joint (default {SEARCH_BUDGET_S:g}: about 25 s of one core; inf: every joint it '
                         'would search)')
    add_no_progress_option(ap)
    return ap


def main(argv=None) -> int:
    ap = build_parser()
    args = ap.parse_args(argv)
    try:
        return _main(ap, args)
    except KeyboardInterrupt:
        return interrupted(ap.prog)


def _main(ap, args) -> int:
    try:
        joints = None
        if args.joints:
            bad = [j for j in args.joints if j not in ALL_JOINTS]
            if bad:
                raise RecordingError(f'--joints: unknown joint(s) {bad}; names are leg<1..6>_<coxa|femur|tibia>')
            joints = tuple(Joint.parse(j) for j in args.joints)
        windows = parse_windows(args.windows) if args.windows else None
        robot = load_robot(args.robot, overlays=args.overlay)
        with warnings.catch_warnings(record=True) as caught:      # a damaged bag: read what is there, say so
            warnings.simplefilter('always', BagWarning)
            rec = load_recording(args.bag, robot)
        # said once the analysis stands: a refusal of the damaged recording is one line that names the damage
        line = one_warning([w.message for w in caught if issubclass(w.category, BagWarning)])
        for w in caught:
            if not issubclass(w.category, BagWarning):
                warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
        settings = FitSettings(min_ratio=args.min_ratio)
        if args.candidates:
            settings.candidates = tuple(args.candidates)
        ground = None if args.terrain in (None, 'none') else Ground(args.terrain, args.terrain_seed, tuple(args.start_xy))
        result = analyse(rec, robot, joints=joints, windows=windows, mode=args.mode, settings=settings,
                         block_s=args.holdout_block, progress=args.progress, ground=ground,
                         whole_walk=args.terrain != 'none', search_budget_s=args.search_budget)
    except (RecordingError, DescriptionError, ValueError) as exc:
        print(f'{ap.prog}: error: {" ".join(str(exc).split())}', file=sys.stderr)
        return 2
    if line:
        print(f'{ap.prog}: warning: {line}', file=sys.stderr)
    from hexapod_sim.discrepancy.report import overlay_yaml, text_report, to_json
    print(text_report(result))
    if args.json:
        open_for_writing(args.json).write_text(json.dumps(to_json(result, args.bag), indent=2) + '\n')
        print(f'\nJSON written to {args.json}')
    if args.write_overlay:
        open_for_writing(args.write_overlay).write_text(overlay_yaml(result))
        print(f'overlay written to {args.write_overlay} (read it with --overlay {args.write_overlay}; '
              'empty when nothing was found)')
    if args.plot:
        from hexapod_sim.discrepancy.plot import save_plot
        save_plot(result, open_for_writing(args.plot))
        print(f'plot written to {args.plot}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
