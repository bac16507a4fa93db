"""./hexapod analyse BAG - offline re-evaluation of a recorded walk, without ROS running.

For every swing-down in the bag (``/swing_down`` holds the inputs of Algorithm 1), the femur reads
the recorded controller decided on are fed through both detectors, adaptive (Eq. 17) and fixed, and
each leg's stop is compared with what the recorded controller did (``/ground_detection``). Those
reads are the ``/joint_states`` messages whose stamps ``/ground_detection`` names, in the order the
controller took them (the j-th read of each leg belongs to step j): over DDS the bus master reads
on its own schedule and the controller takes the newest read of each femur, so the bag's
``/joint_states`` hold more reads than it used, and not always in Algorithm 1's order. A bag
without a complete ``/ground_detection`` for a swing-down is replayed from all its ``/joint_states``
in bus order; a swing-down whose reads are then out of Algorithm 1's order cannot be replayed,
and the report says how many. The detector the recording ran with must reproduce the recorded
decisions exactly. The other detector
can only be judged up to the moment the recorded controller froze the leg (its later reads no
longer show the motion that detector would have commanded); a stop it would have made after that
is reported as "later". Cost of transport, speed and stability are added when the bag carries
power, body pose and IMU. Plots go to a PNG.
"""
from __future__ import annotations

import bisect
import json
import math
import sys
import warnings
from collections import defaultdict
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from hexapod_locomotion.core.detector import STOP_THETA_FIN, DetectorError, phase_from_fields, replay_swing_down
from hexapod_locomotion.core.metrics import MetricsError, roll_pitch_yaw, swing_down_variances, walk_cost_of_transport
from hexapod_model.cli_common import (
    add_no_progress_option,
    interrupted,
    make_parser,
    open_for_writing,
    output_file,
    plot_extensions,
)
from hexapod_model.contract import GROUND_DETECTION, IMU, JOINT_COMMANDS, JOINT_STATES, POWER, SIM_TRUTH_POSE, SWING_DOWN
from hexapod_model.description import LEGS, DescriptionError, joint_name, load_robot, parse_joint_name
from hexapod_model.swing_model import LegModel
from hexapod_sim.bagio import BagError, BagWarning, load_bag, one_warning


class AnalysisError(RuntimeError):
    """The bag cannot be analysed (the message says what is missing)."""


@dataclass
class LegVerdict:
    swing_index: int
    leg: int
    t_start_s: float
    recorded_detector: str
    recorded_stop_s: float | None       # relative to the swing-down start
    recorded_reason: int | None
    replay_same_stop_s: float | None
    replay_same_reason: int | None
    reproduced: bool
    other_detector: str
    other_stop_s: float | None
    other_reason: int | None
    other_verdict: str                  # 'same', 'earlier', 'later', 'undecided'


@dataclass
class SwingTrace:
    legs: tuple
    t_start_s: float
    detector: str                       # the detector the recording ran with
    traces: dict                        # detector -> leg -> list of (t_swing, err, threshold)


@dataclass(frozen=True)
class BagViews:
    """What the re-run takes from a bag (:func:`hexapod_sim.bagio.load_bag`), in the shapes it replays."""

    swings: list                # (stamp [s], /swing_down message), in log order
    femur_reads: list           # (stamp [s], leg, femur angle [rad]) of /joint_states, sorted by stamp
    recorded: dict              # swing start (rounded) -> leg -> (stop time since the start [s], stop reason)
    consumed: dict              # swing start (rounded) -> leg -> stamps [ns] the controller read
    femur_at: dict              # (leg, stamp [ns]) -> (femur angle, stamp [s])
    commands: list              # (stamp [s], frozenset of joint names) of /joint_commands, sorted by stamp
    warnings: list              # the reader's problems with a damaged bag


def bag_views(path: str) -> tuple[BagViews, object]:
    """The re-run's views of the bag at ``path`` and the bag's contents (for the walk's metrics)."""
    with warnings.catch_warnings():      # the problems are returned (contents.warnings) and reported by the caller
        warnings.simplefilter('ignore', BagWarning)
        bag = load_bag(path, topics=(SWING_DOWN, JOINT_STATES, JOINT_COMMANDS, GROUND_DETECTION, POWER,
                                     SIM_TRUTH_POSE, IMU),
                       required={SWING_DOWN: 'the swing-down inputs of Algorithm 1 were not recorded (record with '
                                             './hexapod demo or a locomotion_node of this version)',
                                 JOINT_STATES: 'there are no servo reads to analyse'})
    if not bag.swing_downs:
        raise AnalysisError(f'{path}: /{SWING_DOWN} has no messages - the recording contains no swing-down')
    femur_reads, femur_at = [], {}
    js = bag.joint_states
    for t_s, t_ns, names, positions in zip(js.stamp_s, js.stamp_ns, js.name, js.position):
        for name, pos in zip(names, positions):
            try:
                leg, role = parse_joint_name(name)
            except DescriptionError:
                continue
            if role == 'femur':
                femur_reads.append((t_s, leg, pos))
                femur_at[(leg, t_ns)] = (pos, t_s)
    recorded = defaultdict(dict)
    consumed = defaultdict(lambda: defaultdict(list))
    for d in bag.detections:
        start = round(d.swing_start_s, 6)
        consumed[start][d.leg].append(d.t_ns)
        if d.stopped and d.leg not in recorded[start]:
            recorded[start][d.leg] = (d.t_s - d.swing_start_s, d.stop_reason)
    femur_reads.sort(key=lambda r: r[0])
    cmd = bag.joint_commands
    commands = sorted(zip(cmd.stamp_s, (frozenset(n) for n in cmd.name)), key=lambda c: c[0])
    return BagViews([(s.t_s, s.msg) for s in bag.swing_downs], femur_reads, recorded, consumed, femur_at, commands,
                    list(bag.warnings)), bag


def controller_reads(consumed: dict, femur_at: dict, legs) -> list | None:
    """The femur reads ``(leg, theta_rad, stamp_s)`` the recorded controller decided on in one
    swing-down, in Algorithm 1's order (step by step, each step's legs in ``legs`` order), from the
    stamps its ``/ground_detection`` names and the angles of those reads in ``/joint_states``.
    None when they do not make whole steps (a message lost) or a read is not in the bag."""
    per_leg = {leg: sorted(set(consumed.get(leg, ()))) for leg in legs}
    n = len(per_leg[legs[0]]) if legs else 0
    if not n or any(len(v) != n for v in per_leg.values()):
        return None
    out = []
    for k in range(n):
        for leg in legs:
            t_ns = per_leg[leg][k]
            read = femur_at.get((leg, t_ns))
            if read is None:
                return None
            out.append((leg, *read))            # the stamp as the controller computed it from the message
    return out


def swing_down_writes(commands, legs, t0: float, t_end: float) -> list[float]:
    """Stamps of the goal writes of the swing-down of ``legs`` that began at ``t0``: the recorded
    ``/joint_commands`` (sorted by stamp) from ``t0`` on (before ``t_end``) that name exactly the
    group's joints, one per step of Algorithm 1 (:func:`~hexapod_locomotion.core.detector.replay_swing_down`).
    Empty for a bag without ``/joint_commands``: the replay then uses the nominal schedule."""
    names = frozenset(joint_name(leg, r) for leg in legs for r in ('coxa', 'femur', 'tibia'))
    lo = bisect.bisect_left(commands, t0 - 1e-9, key=lambda c: c[0])       # commands are sorted by stamp
    hi = bisect.bisect_left(commands, t_end, lo=lo, key=lambda c: c[0])
    return [t for t, n in commands[lo:hi] if n == names]


def _replay_both(robot, msg, t0: float, i: int, reads: list, writes: list, taken: bool, models: dict,
                 problems: list, out_of_order: list) -> tuple[dict, dict, list]:
    """Replay swing-down ``i`` with the recorded detector and the other one: per detector its phase
    and its per-leg read rows, and the reads of this swing-down (those in bus order cut at the step
    in which the recorded detector's last leg stopped). A detector's error goes to ``problems``."""
    kind = msg.detector
    other = 'fixed' if kind == 'adaptive' else 'adaptive'
    legs = tuple(int(x) for x in msg.legs)
    res, tr = {}, {}
    for det in (kind, other):
        ph = phase_from_fields(robot, msg, t0, kind=det, models=models)
        rows = defaultdict(list)
        try:
            replay_swing_down(ph, reads, writes=writes, on_read=lambda r, rows=rows: rows[r.leg].append(
                (r.t_swing_s, r.err_tick, r.threshold_tick, r.stopped, r.stop_reason)))
        except DetectorError as exc:
            problems.append(f'swing-down {i} at t={t0:.3f} s, {det} detector: {exc}')
            if det == kind and 'out of Algorithm 1 order' in str(exc):
                out_of_order.append(i)
        res[det] = ph
        tr[det] = dict(rows)
        if det == kind and not taken:
            # the recorded swing-down ended with the step in which its last leg stopped: the
            # bus's reads after it belong to the next phase (background reads), not to this one
            # (the step ends with the read of the last leg in bus order)
            done = [ph.state[leg].stop_time_s + (len(legs) - 1 - slot) * ph.t_com_s
                    for slot, leg in enumerate(legs) if ph.state[leg].stopped]
            if done:
                end = max(done) + 1e-9
                reads = [r for r in reads if r[2] <= end]
    return res, tr, reads


def _leg_verdict(i: int, leg: int, t0: float, kind: str, other: str, res: dict, rec: dict) -> LegVerdict:
    """One leg's stop as recorded, as the recorded detector reproduces it and as the other would have
    decided (earlier, the same, later, or undecided without a recorded decision)."""
    same = res[kind].state[leg]
    oth = res[other].state[leg]
    r_stop, r_reason = rec.get(leg, (None, None))
    s_stop = same.stop_time_s - t0 if same.stopped else None
    o_stop = oth.stop_time_s - t0 if oth.stopped else None
    reproduced = (r_stop is not None and s_stop is not None and abs(r_stop - s_stop) < 1e-6
                  and r_reason == same.stop_reason)
    if r_stop is None:
        verdict = 'undecided'                    # the recording has no decision to compare with
    elif o_stop is None:
        verdict = 'later'                        # no stop before the recorded swing-down ended
    elif abs(o_stop - r_stop) < 1e-6:
        verdict = 'same'
    elif o_stop < r_stop:
        verdict = 'earlier'
    else:
        verdict = 'later'
    return LegVerdict(i, leg, t0, kind, r_stop, r_reason, s_stop, same.stop_reason if same.stopped else None,
                      reproduced, other, o_stop if verdict != 'later' else None,
                      oth.stop_reason if verdict in ('same', 'earlier') else None, verdict)


def _walk_metrics(out: dict, robot, swings, bag, intervals) -> None:
    """Cost of transport (with the body pose and /power) and stability (with the IMU) into ``out``."""
    if len(bag.power) and len(bag.truth_pose):
        tp, pw = np.column_stack([bag.power.t_s, bag.power.values]).T
        ps = np.column_stack([bag.truth_pose.t_s, bag.truth_pose.values])
        try:
            out['cot'] = walk_cost_of_transport(ps[:, 0], ps[:, 1:3], tp, pw, swings[0][0], robot.total_mass_kg,
                                                robot.gravity_mps2)
        except MetricsError as exc:
            out['cot'] = None
            out['cot_note'] = str(exc)
    else:
        out['cot'] = None
        out['cot_note'] = ('no body pose in the bag (a real robot has no external localisation here): speed and CoT '
                           'need /sim/body_pose' if len(bag.power) else 'no /power in the bag')
    imu = bag.imu
    if len(imu):
        rp = np.array([roll_pitch_yaw(q)[:2] for q in imu.quat_wxyz.tolist()]).reshape(-1, 2)
        a = np.column_stack([imu.t_s, rp, imu.accel[:, 2]])
        st = swing_down_variances(a[:, 0], a[:, 1], a[:, 2], a[:, 3], intervals)
        out['stability'] = {k: float(np.median([s[k] for s in st])) for k in ('var_roll', 'var_pitch', 'var_acc_z')} if st else None


def rerun_detectors(path: str, robot=None, keep_traces: int = 6, progress: bool = False) -> dict:
    """Re-run both detectors over the bag at ``path``.

    A recording can end in the middle of a swing-down (a truncated bag, or a walk stopped at its
    time limit): when the last swing-down has a leg without a recorded decision, that swing-down
    is reported as ``incomplete`` and left out of every count, as the demo leaves out a gait
    phase cut off by its time limit.
    """
    robot = robot or load_robot()
    views, bag = bag_views(path)
    swings, femur_reads, recorded, commands = views.swings, views.femur_reads, views.recorded, views.commands
    consumed, femur_at = views.consumed, views.femur_at
    models = {leg: LegModel(robot, leg) for leg in LEGS}
    times = np.array([r[0] for r in femur_reads])
    verdicts: list[LegVerdict] = []
    traces: list[SwingTrace] = []
    intervals = []
    problems: list[str] = []
    incomplete = []
    out_of_order = []                   # swing-downs replayed from the bus's reads, which broke Algorithm 1's order
    from tqdm import tqdm
    for i, (t0, msg) in enumerate(tqdm(swings, desc='re-running the detectors', unit='swing-down',
                                       file=sys.stderr, disable=not progress, leave=False)):
        t_end = swings[i + 1][0] if i + 1 < len(swings) else math.inf
        legs = tuple(int(x) for x in msg.legs)
        rec = recorded.get(round(t0, 6), {})
        if i == len(swings) - 1 and any(leg not in rec for leg in legs):
            incomplete.append({'swing_index': i, 't_start_s': t0, 'legs': list(legs),
                               'legs_with_a_decision': sorted(rec)})
            continue
        reads = controller_reads(consumed.get(round(t0, 6), {}), femur_at, legs)
        taken = reads is not None
        if not taken:               # no complete /ground_detection: every recorded read, in bus order
            lo, hi = np.searchsorted(times, t0 - 1e-9), np.searchsorted(times, t_end - 1e-9)
            reads = [(leg, th, t) for t, leg, th in femur_reads[lo:hi] if leg in legs]
        writes = swing_down_writes(commands, legs, t0, t_end)
        res, tr, reads = _replay_both(robot, msg, t0, i, reads, writes, taken, models, problems, out_of_order)
        if len(traces) < keep_traces:
            traces.append(SwingTrace(legs, t0, msg.detector, tr))
        other = 'fixed' if msg.detector == 'adaptive' else 'adaptive'
        for leg in legs:
            verdicts.append(_leg_verdict(i, leg, t0, msg.detector, other, res, rec))
            if verdicts[-1].recorded_stop_s is not None:
                intervals.append((t0, t0 + verdicts[-1].recorded_stop_s, leg))
    out: dict = {'bag': str(path), 'swing_downs': len(swings) - len(incomplete), 'legs_evaluated': len(verdicts),
                 'incomplete_swing_downs': incomplete, 'out_of_order_swing_downs': out_of_order,
                 'recorded_detector': sorted({v.recorded_detector for v in verdicts}),
                 'reproduced': sum(v.reproduced for v in verdicts),
                 'not_reproduced': [asdict(v) for v in verdicts if not v.reproduced],
                 'other_detector': {k: sum(v.other_verdict == k for v in verdicts)
                                    for k in ('same', 'earlier', 'later', 'undecided')},
                 'other_earlier_by_s': _stats([v.recorded_stop_s - v.other_stop_s for v in verdicts
                                               if v.other_verdict == 'earlier']),
                 'verdicts': [asdict(v) for v in verdicts], 'problems': problems,
                 'bag_warnings': views.warnings}
    _walk_metrics(out, robot, swings, bag, intervals)
    out['_traces'] = traces
    return out


def _stats(values):
    if not values:
        return None
    a = np.array(values)
    return {'n': len(a), 'median': float(np.median(a)), 'max': float(a.max())}


def plot(result: dict, path: Path) -> list[str]:
    """The first swing-downs' error traces, both thresholds and where each detector stopped each leg
    (threshold crossed, or theta_fin reached without a detection); returns the legend's labels."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    traces = result['_traces']
    if not traces:
        return []
    fig, axes = plt.subplots(len(traces), 1, figsize=(9, 2.4 * len(traces)), squeeze=False)
    colours = plt.rcParams['axes.prop_cycle'].by_key()['color']
    seen = set()                       # each stop marker is named once in the legend
    for ax, tr in zip(axes[:, 0], traces):
        for slot, leg in enumerate(tr.legs):
            c = colours[slot % len(colours)]
            for det, style, mark in (('adaptive', '--', 'o'), ('fixed', ':', 's')):
                rows = tr.traces.get(det, {}).get(leg, [])
                n = next((i + 1 for i, r in enumerate(rows) if r[3]), len(rows))   # up to the stop
                a = np.array(rows[:n]) if n else np.zeros((0, 5))
                if not len(a):
                    continue
                recorded = det == tr.detector
                if recorded:
                    ax.plot(a[:, 0], a[:, 1], '-', color=c, lw=1, label=f'leg {leg}: measured error')
                if det == 'adaptive':
                    ax.plot(a[:, 0], a[:, 2], style, color=c, lw=1, label=f'leg {leg}: adaptive threshold (Eq. 17)')
                else:
                    ax.plot(a[:, 0], a[:, 2], style, color='0.5', lw=1, label='fixed threshold' if slot == 0 else None)
                if rows[n - 1][3]:      # this detector stopped the leg here (filled: the recorded detector)
                    fin = rows[n - 1][4] == STOP_THETA_FIN      # no contact detected: the leg ran to theta_fin
                    what = f'{det}: ran to theta_fin' if fin else f'{det} stop (threshold crossed)'
                    label = what + (' (recorded)' if recorded else '')
                    ax.plot(a[-1, 0], a[-1, 1], 'x' if fin else mark, color=c, ms=6 if fin else 5,
                            mfc=c if recorded else 'none', label=None if label in seen else label)
                    seen.add(label)
        ax.set_title(f'swing-down at t={tr.t_start_s:.2f} s, legs {tr.legs} (o adaptive stop, s fixed stop, '
                     f'x theta_fin reached; filled: recorded)', fontsize=9)
        ax.set_ylabel('lag [ticks]')
        ax.grid(alpha=0.3)
    axes[-1, 0].set_xlabel('time since swing-down start [s]')
    legend = {}                        # every axes' labels (a stop kind may first occur further down)
    for ax in axes[:, 0]:
        for h, lab in zip(*ax.get_legend_handles_labels()):
            legend.setdefault(lab, h)
    axes[0, 0].legend(legend.values(), legend.keys(), fontsize=6, ncol=4, loc='lower left', bbox_to_anchor=(0, 1.15))
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return list(legend)


def report_lines(r: dict, json_path: str | None = None) -> list[str]:
    """The text report; uses the demo's words: swing-down phases (one per leg group) and leg swing-downs."""
    lines = [f'{r["bag"]}: {r["swing_downs"]} swing-down phases, {r["legs_evaluated"]} leg swing-downs, recorded '
             f'with the {"/".join(r["recorded_detector"])} detector']
    for inc in r.get('incomplete_swing_downs', []):
        lines.append(f'  the recording ends during the swing-down at t={inc["t_start_s"]:.2f} s (legs {inc["legs"]}, '
                     f'{len(inc["legs_with_a_decision"])} of {len(inc["legs"])} with a decision): incomplete, '
                     'left out of the counts')
    bad = r.get('out_of_order_swing_downs', [])
    if bad:
        lines.append(f'  {len(bad)} of {r["swing_downs"]} swing-down phases cannot be replayed: the recorded reads are '
                     'out of Algorithm 1 order and the bag does not say which reads the controller took '
                     '(no complete /ground_detection); their decisions are not reproduced')
    differ = len(r['not_reproduced'])
    lines.append(f'  re-running the recorded detector reproduces {r["reproduced"]} of {r["legs_evaluated"]} decisions'
                 + ('' if not differ else f' ({differ} differ' + (f'; see {json_path})' if json_path else
                                                                  '; --json FILE lists them)')))
    o = r['other_detector']
    other = 'fixed' if r['recorded_detector'] == ['adaptive'] else 'adaptive'
    lines.append(f'  the {other} detector would have stopped: same read {o["same"]}, earlier {o["earlier"]}, '
                 f'later than the recorded stop {o["later"]}, undecided {o["undecided"]}')
    if r['other_earlier_by_s']:
        lines.append(f'    earlier by median {r["other_earlier_by_s"]["median"] * 1e3:.0f} ms '
                     f'(max {r["other_earlier_by_s"]["max"] * 1e3:.0f} ms)')
    if r.get('cot'):
        c = r['cot']
        lines.append(f'  speed {c["speed_mps"]:.3f} m/s, mean power {c["power_w"]:.1f} W, cost of transport '
                     f'{c["cot"]:.1f} (Eq. 18, {c["windows"]} windows of 10 s)')
    elif r.get('cot_note'):
        lines.append(f'  CoT: {r["cot_note"]}')
    if r.get('stability'):
        s = r['stability']
        lines.append(f'  swing-down stability (median per-leg variance): roll {s["var_roll"]:.2e}, '
                     f'pitch {s["var_pitch"]:.2e}, acc_z {s["var_acc_z"]:.2e}')
    return lines


def main(argv=None) -> int:
    ap = make_parser('analyse', __doc__)
    ap.add_argument('bag', help='rosbag2 directory or .mcap file')
    ap.add_argument('--json', metavar='FILE', type=output_file(('.json',), create_parent=True),
                    help='write the full analysis as JSON (its folder is created)')
    ap.add_argument('--plot', metavar='PNG', type=output_file(plot_extensions, create_parent=True),
                    help='plot measured error, both thresholds and both detectors\' stops of the first swing-downs')
    ap.add_argument('--labels', metavar='FILE', help='terrain label file (START_S END_S LABEL per line): the '
                    'confusion of the terrain timeline against it (docs/terrain.md)')
    add_no_progress_option(ap)
    args = ap.parse_args(argv)
    try:
        return _analyse(ap, args)
    except KeyboardInterrupt:
        return interrupted(ap.prog, 'nothing written')


def _analyse(ap, args) -> int:
    try:
        r = rerun_detectors(args.bag, progress=args.progress)
    except (BagError, AnalysisError, DetectorError) as exc:
        print(f'{ap.prog}: error: {exc}', file=sys.stderr)
        return 2
    line = one_warning(r['bag_warnings'])
    if line:
        print(f'{ap.prog}: warning: {line}', file=sys.stderr)
    for line in report_lines(r, args.json):
        print(line)
    from hexapod_locomotion.core.terrain_model import TerrainModelError
    from hexapod_locomotion.trials.terrain_data import TerrainDataError
    from hexapod_locomotion.trials.terrain_report import report_lines as terrain_lines
    try:
        for line in terrain_lines(args.bag, load_robot(), args.labels):
            print(line)
    except (TerrainDataError, TerrainModelError) as exc:
        if args.labels:              # the terrain was asked for
            print(f'{ap.prog}: error: {exc}', file=sys.stderr)
            return 2
        print(f'terrain: not classed ({" ".join(str(exc).split())})')
    if args.plot:
        plot(r, open_for_writing(args.plot))
        print(f'plot: {args.plot}')
    if args.json:
        open_for_writing(args.json).write_text(json.dumps({k: v for k, v in r.items() if k != '_traces'}, indent=1))
        print(f'JSON: {args.json}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
