"""Random benchmark of the discrepancy tool on concealed data (not a test): ``./hexapod random-bench``.

A seeded generator draws concealed-effect cases beside the fixed ones of
:mod:`~hexapod_locomotion.bench.discrepancy_bench` and :mod:`~hexapod_locomotion.bench.dictionary_bench`:

* one effect or a pair of effects (a pair: at most one on the whole robot, the others on different joints);
* in-list effects (the candidates of the tool, magnitudes from ``discrepancy_bench.RANGES``) on one joint,
  one leg (a payload always on a leg) or the whole robot; out-of-list physics (the dictionary terms
  of ``dictionary_bench.CASES``: cable spring, angle-periodic friction, load-proportional friction,
  weak or slow motor, supply sag), each parameter drawn around that case's value; servo-law differences
  (punch, motor damping, goal latency: the firmware of every servo);
* the stand calibration routine of one leg, or a walk of the gait controller on the MuJoCo terrain
  (tripod, tetrapod or pentapod; flat ground or the blocks of one of three seeds; the calibration cycle or
  the controller's default cycle).

Every case has a **clean twin**: the same routine, or the same walk (gait, ground, cycle, length), without
the effects. The twins are the same for cases that share the routine or the walk (the sim is
deterministic), so each is recorded once, analysed, and passed to its cases.

**Visibility (the truth of what a recording shows).** Per effect ``E`` of a case, every read is compared
with what the sim would have given without ``E`` (with the case's other effects), per joint and phase:
on a stand the commands are the same, so the recording is compared read by read with a recording of the
same routine without ``E`` (for a single effect: the twin); on a walk the controller reacts to the
effect, so the walk's own recorded goals are replayed open loop through the MuJoCo hexapod without ``E``
on the same ground (:func:`hexapod_sim.discrepancy.whole_walk.replay_walk`) and the residual's RMS in
every joint and gait phase is set against the twin's own replay residual there (tick rounding and the
model's mismatch). ``E`` is visible on a joint where in some phase with at least ``MIN_PHASE_READS`` reads
that RMS exceeds the baseline by more than ``VISIBLE_MARGIN_TICKS``.

**Score.** A case is right when every effect visible on some joint is found and nothing false is
claimed (:func:`score`): an in-list or servo-law effect by name (a robot-wide readout delay or viscous
damping also as its servo-law twin), on joints within the truth's and covering every joint it is visible
on (a payload: legs), with its parameter within ``discrepancy_bench.TOLERANCE``; an out-of-list term by
the right dictionary term in ``physics_terms`` (parameters within the tolerance of its
``dictionary_bench`` case, scaled to the drawn value) or by an ``unexplained`` entry at a joint it is
visible on. A list candidate named on an out-of-list effect's joints is *misnamed*; any other effect,
term or unexplained joint outside the truth is *false*. A clean twin is right when the tool claims
nothing, an invisible case when it claims nothing false.
"""
from __future__ import annotations

import contextlib
import io
import json
import math
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from hexapod_locomotion.bench import discrepancy_bench as fixed
from hexapod_locomotion.bench.random_cases import (
    RandomCase,
    categories,
    draw_case,
    legs_of,
    make_cases,
    phase_rms,
    scope_label,
    stand_labels,
    stand_residual,
    visible_joints,
    walk_phase_rms,
)
from hexapod_model.description import ALL_JOINTS, Effect, load_robot
from hexapod_model.dictionary import BY_TERM
from hexapod_model.joints import joint_names
from hexapod_sim.discrepancy.effects import BY_NAME

WALK_S = 12.0                 # simulated walking time of a walk case (see docs/discrepancy.md, "Random bench")
GOAL_RIGHT = 0.9


# ----------------------------------------------------------------------------- scoring
def _rel_ok(fitted: float, truth: float, tol: float) -> tuple[bool, float]:
    err = abs(fitted - truth) / abs(truth)
    return bool(err <= tol), float(err)


def _term_ok(params: dict, truth: Effect, tol: dict) -> tuple[bool, float]:
    """Every toleranced parameter of a term within its tolerance; the worst share of the tolerance used."""
    worst = 0.0
    for key, (t, kind) in tol.items():
        if key not in params:
            return False, math.inf
        d = abs(params[key] - truth.params[key])
        used = (d / abs(truth.params[key]) if kind == 'rel' else d) / t
        worst = max(worst, used)
    return worst <= 1.0, worst


def _as_servo_law(found: dict, case: RandomCase) -> dict:
    """A joint effect found where the truth holds its servo-law twin and not the joint effect, in the
    servo law's words (a readout delay is a goal latency to a free leg's replay; viscous damping is motor
    damping of ratio ``1 + b / b_motor``), so that on too few joints it is scored as wrong joints."""
    twin = {'readout_delay': 'goal_latency', 'viscous_damping': 'motor_damping'}.get(found['effect'])
    names = {e.effect for e in case.effects}
    if twin is None or twin not in names or found['effect'] in names:
        return found
    v = next(iter(found['params'].values()))
    if twin == 'motor_damping':
        v = 1.0 + v / load_robot().servo.reflected_damping_nms_per_rad
    return {**found, 'effect': twin, 'params': {BY_NAME[twin].key: float(v)}}


def score(case: RandomCase, result: dict, visible: list) -> dict:
    """Score the tool's JSON ``result`` against ``case``'s truth; ``visible`` per effect: the joints
    it is visible on (``{}``/``[]``: not shown). See the module docstring for the rules."""
    analysed = set(result.get('joints', {}))
    # a robot-wide truth in the tool's words: every analysed joint
    seen = [Effect(e.effect, tuple(j for j in e.joints if str(j) in analysed) or e.joints, dict(e.params))
            if len(e.joints) == len(ALL_JOINTS) else e for e in case.effects]
    found = [_as_servo_law(fixed._as_truth_names(f, case.bench_case('score', seen)), case)
             for f in result.get('effects', [])]
    terms = list(result.get('physics_terms', []))
    unexplained = list(result.get('unexplained', []))
    used_f, used_t, used_u = set(), set(), set()
    rows = []
    for k, (t, cls) in enumerate(zip(case.effects, case.classes)):
        on = set(joint_names(t.joints))                 # the truth in the JSON's words
        vis = sorted(set(visible[k]) & analysed & on) if k < len(visible) else []
        tol = case.tolerance[k] if k < len(case.tolerance) else {}
        row = {'effect': t.effect, 'class': cls, 'scope': scope_label(t.joints), 'truth': dict(t.params),
               'visible': vis, 'found': False, 'how': None, 'fitted': None, 'param_error': None, 'verdict': None}
        if cls == 'out-of-list':
            cand = [i for i, f in enumerate(terms) if f['term'] == t.effect and i not in used_t
                    and (BY_TERM[t.effect].robot_wide or set(f['joints']) <= on)]
            if cand:
                i = cand[0]
                used_t.add(i)
                ok, used = _term_ok(terms[i]['params'], t, tol)
                row.update(found=True, how='term', fitted=dict(terms[i]['params']), param_error=used)
                row['verdict'] = 'right' if ok else 'parameter off'
            where = on if not BY_TERM[t.effect].robot_wide else analysed
            near = [i for i, u in enumerate(unexplained) if set(u['joints']) & where]
            used_u |= set(near)
            if row['verdict'] != 'right' and any(set(unexplained[i]['joints']) & set(vis) for i in near):
                row.update(found=True, how='unexplained', verdict='right')
        else:
            key = BY_NAME[t.effect].key
            # the same effect on joints that overlap the truth's; right where they lie within the truth's
            # and cover every joint it is visible on (a payload: legs)
            if t.effect == 'mass_error':
                cand = [i for i, f in enumerate(found) if f['effect'] == t.effect and i not in used_f
                        and legs_of(f['joints']) & legs_of(t.joints)]
                covers = [i for i in cand if legs_of(vis) <= legs_of(found[i]['joints']) <= legs_of(t.joints)]
            else:
                cand = [i for i, f in enumerate(found) if f['effect'] == t.effect and i not in used_f
                        and set(f['joints']) & on]
                covers = [i for i in cand if set(vis) <= set(found[i]['joints']) <= on]
            pick = (covers or cand or [None])[0]
            if pick is not None:
                used_f.add(pick)
                f = found[pick]
                ok, err = _rel_ok(f['params'][key], t.params[key], fixed.TOLERANCE[t.effect])
                row.update(found=True, how='effect', fitted=f['params'][key], param_error=err)
                row['verdict'] = ('right' if ok and pick in covers else 'wrong joints' if pick not in covers
                                  else 'parameter off')
        if not vis and row['verdict'] != 'right':
            row['verdict'] = 'not shown' if not row['found'] else 'not shown (' + row['verdict'] + ')'
        elif row['verdict'] is None:
            row['verdict'] = 'not found'
        rows.append(row)
    off_list = [t for t, c in zip(case.effects, case.classes) if c == 'out-of-list']
    misnamed, false = [], []
    for i, f in enumerate(found):
        if i in used_f:
            continue
        if any(BY_TERM[t.effect].robot_wide or set(f['joints']) & set(joint_names(t.joints)) for t in off_list):
            misnamed.append(f)
        else:
            false.append(f)
    truth_joints = set().union(*(set(joint_names(t.joints)) for t in case.effects)) if case.effects else set()
    false += [{'term': f['term'], 'joints': f['joints'], 'params': f['params']}
              for i, f in enumerate(terms) if i not in used_t]
    false += [{'unexplained': u['joints'], 'heldout_rmse_ticks': u.get('heldout_rmse_ticks')}
              for i, u in enumerate(unexplained) if i not in used_u and not set(u['joints']) & truth_joints]
    shown = any(r['visible'] for r in rows)
    right = all(r['verdict'] == 'right' or r['verdict'].startswith('not shown') for r in rows) \
        and not misnamed and not false
    return {'rows': rows, 'misnamed': misnamed, 'false': false, 'visible': shown, 'right': bool(right)}


def score_clean(result: dict) -> dict:
    """A clean twin: right when the tool claims nothing (no effect, no term, no unexplained joint)."""
    claims = (list(result.get('effects', [])) + list(result.get('physics_terms', []))
              + [{'unexplained': u['joints']} for u in result.get('unexplained', [])])
    return {'false': claims, 'right': not claims}


def failure_kinds(s: dict) -> list[str]:
    """What went wrong in a scored case (empty: right)."""
    kinds = [f'{r["class"]} {r["effect"]}: {r["verdict"]}' for r in s['rows']
             if r['verdict'] != 'right' and not r['verdict'].startswith('not shown')]
    kinds += [f'misnamed: {f["effect"]} for out-of-list physics' for f in s['misnamed']]
    kinds += ['false: ' + (f'{f["effect"]}' if 'effect' in f else f'term {f["term"]}' if 'term' in f
                           else f'unexplained {",".join(f["unexplained"])}') for f in s['false']]
    return kinds


# ----------------------------------------------------------------------------- running
def _tool(bag: Path, work: Path, reuse: bool = False) -> tuple[dict, float]:
    """Run the discrepancy tool's command line on ``bag`` in process; its JSON result and wall time
    (``reuse``: the result kept from an earlier run, and the analysis time its report states)."""
    import re

    from hexapod_sim.discrepancy.cli import main as tool
    js = work / (bag.name + '.json')
    txt = work / (bag.name + '.txt')
    if reuse and js.exists() and txt.exists():
        took = re.search(r'analysis took ([0-9.]+) s', txt.read_text())
        return json.loads(js.read_text()), float(took.group(1)) if took else math.nan
    t0 = time.perf_counter()
    with contextlib.redirect_stdout(io.StringIO()) as text:
        rc = tool([str(bag), '--json', str(js), '--no-progress'])
    (work / (bag.name + '.txt')).write_text(text.getvalue())
    if rc != 0:
        raise RuntimeError(f'the discrepancy tool failed on {bag} (exit {rc})')
    return json.loads(js.read_text()), time.perf_counter() - t0


def _record(case: RandomCase, name: str, effects, work: Path, walk_s: float, reuse: bool = False):
    """Record ``case``'s routine or walk with ``effects``; -> (bag, Recording). ``reuse``: the bag kept
    from an earlier run of the same seed, if there is one."""
    from hexapod_sim.discrepancy.recording import load_recording
    bc = case.bench_case(name, effects)
    kept = fixed.bag_path(bc, work)
    if reuse and (kept / 'metadata.yaml').exists():
        return kept, load_recording(kept, load_robot())
    if case.walk:
        bag, _ = fixed.record_walk(bc, work, duration_s=walk_s, seed=case.terrain_seed)
    else:
        bag, _ = fixed.record_case(bc, work, legs=(case.leg,), phases=case.phases)
    return bag, load_recording(bag, load_robot())


def _workdir(keep: str | None, prefix: str) -> Path:
    work = Path(keep) if keep else Path(tempfile.mkdtemp(prefix=prefix))
    work.mkdir(parents=True, exist_ok=True)
    return work


def run_twin(job: tuple) -> dict:
    """Record and analyse one clean twin; its score and its visibility baseline (a job of :func:`run`).
    ``job`` = (a case of this twin, keep dir or None, walk seconds, reuse kept bags and results)."""
    case, keep, walk_s, reuse = job
    work = _workdir(keep, 'random_bench_twin_')
    try:
        t0 = time.perf_counter()
        bag, rec = _record(case, case.twin_key, (), work, walk_s, reuse)
        t_rec = time.perf_counter() - t0
        result, t_tool = _tool(bag, work, reuse)
        t0 = time.perf_counter()
        if case.walk:
            base = _cached(work / f'{case.twin_key}.base.json', keep, reuse, lambda: walk_phase_rms(rec, load_robot()))
        else:
            base = {j: (s.t_s, s.theta_rad) for j, s in rec.states.items()}
        t_vis = time.perf_counter() - t0
        return {'key': case.twin_key, 'setting': case.setting, 'score': score_clean(result), 'base': base,
                'record_s': t_rec, 'tool_s': t_tool, 'visibility_s': t_vis, 'duration_s': rec.duration_s,
                'result': _brief(result)}
    finally:
        if not keep:
            shutil.rmtree(work, ignore_errors=True)


def _brief(result: dict) -> dict:
    """What a scored case keeps of the tool's JSON."""
    return {k: result.get(k) for k in ('joints', 'effects', 'physics_terms', 'unexplained', 'cannot_show')}


class _Reads:
    """A recording's reads as :func:`stand_residual` takes them (a twin's base, passed between processes)."""

    def __init__(self, base: dict):
        from types import SimpleNamespace
        self.states = {j: SimpleNamespace(t_s=np.asarray(t), theta_rad=np.asarray(th)) for j, (t, th) in base.items()}


def run_case(job: tuple) -> dict:
    """Record one case, run the tool on its bag, judge what it shows and score it (a job of :func:`run`).
    ``job`` = (case, its twin's :func:`run_twin` result, keep dir or None, walk seconds, reuse). A case that
    fails (the tool exits non-zero or raises) is scored wrong with the error as its failure, so the
    other cases still run."""
    case = job[0]
    try:
        return _run_case(*job)
    except Exception as exc:      # noqa: BLE001 - reported as the case's failure
        return {'rows': [], 'misnamed': [], 'false': [], 'visible': True, 'right': False, 'index': case.index,
                'label': case.label, 'twin': case.twin_key, 'categories': categories(case), 'visibility': [],
                'cannot_show_contradicted': {}, 'failures': [f'error: {type(exc).__name__}: {str(exc)[:200]}'],
                'record_s': 0.0, 'tool_s': 0.0, 'visibility_s': 0.0, 'duration_s': 0.0, 'result': {}}


def _run_case(case: RandomCase, twin: dict, keep: str | None, walk_s: float, reuse: bool = False) -> dict:
    work = _workdir(keep, 'random_bench_case_')
    name = f'case{case.index:03d}'
    try:
        t0 = time.perf_counter()
        bag, rec = _record(case, name, case.effects, work, walk_s, reuse)
        t_rec = time.perf_counter() - t0
        result, t_tool = _tool(bag, work, reuse)
        t0 = time.perf_counter()
        detail = _cached(work / f'{name}.visibility.json', keep, reuse,
                         lambda: _visibility(case, rec, twin, work, walk_s, reuse))
        t_vis = time.perf_counter() - t0
        return scored(case, result, detail, record_s=t_rec, tool_s=t_tool, visibility_s=t_vis,
                      duration_s=rec.duration_s)
    finally:
        if not keep:
            shutil.rmtree(work, ignore_errors=True)


def _cached(path: Path, keep, reuse: bool, compute):
    """``compute()``, kept as JSON in ``path`` when there is a keep dir; read back from there with ``reuse``."""
    if reuse and path.exists():
        return json.loads(path.read_text())
    value = compute()
    if keep:
        path.write_text(json.dumps(value, default=_jsonable))
    return value


def _visibility(case: RandomCase, rec, twin: dict, work: Path, walk_s: float, reuse: bool) -> list:
    """Per effect of ``case``: the joints its recording ``rec`` shows it on, joint -> [(phase, excess RMS)]."""
    name = f'case{case.index:03d}'
    robot = load_robot()
    detail = []
    for k, e in enumerate(case.effects):
        others = case.without(k)
        if case.walk:
            rms = walk_phase_rms(rec, robot.with_effects(others) if others else robot)
            detail.append(visible_joints(rms, twin['base']))
        else:
            other = (_Reads(twin['base']) if not others else
                     _record(case, f'{name}_without_{k}', others, work, walk_s, reuse)[1])
            labels, names = stand_labels(rec, (case.leg,), case.phases)
            detail.append(visible_joints(phase_rms(stand_residual(rec, other), labels, names), None))
    return detail


def scored(case: RandomCase, result: dict, visibility: list, **timing) -> dict:
    """A case's result: :func:`score` of the tool's JSON against the visibility found (per effect: joint ->
    [(phase, excess RMS)]), what else the report shows, and ``timing`` [s]."""
    s = score(case, result, [sorted(v) for v in visibility])
    contradicted = {r['effect']: sorted(set(result.get('cannot_show', {}).get(r['effect'], ())) & set(r['visible']))
                    for r in s['rows'] if r['verdict'] != 'right'}
    s.update(index=case.index, label=case.label, twin=case.twin_key, categories=categories(case),
             visibility=visibility, cannot_show_contradicted={k: v for k, v in contradicted.items() if v},
             failures=failure_kinds(s), result=_brief(result), **timing)
    return s


def rescore(run_json: dict, keep: Path) -> tuple[list[dict], dict]:
    """Score a kept run again (its ``--json`` output and the tool's results kept in ``keep``) with the
    scorer of this version: no recording, no analysis. -> as :func:`run`."""
    results = []
    for r in run_json['cases']:
        case = draw_case(run_json['seed'], r['index'])
        timing = {k: r[k] for k in ('record_s', 'tool_s', 'visibility_s', 'duration_s')}
        bag = fixed.bag_path(case.bench_case(f'case{case.index:03d}'), keep)
        js = keep / (bag.name + '.json')
        if not r['visibility'] or not js.exists():
            results.append(r)          # a case that failed: its error stands
            continue
        results.append(scored(case, json.loads(js.read_text()), r['visibility'], **timing))
    twins = {}
    for t in run_json['twins']:
        case = next(draw_case(run_json['seed'], r['index']) for r in run_json['cases']
                    if r['twin'] == t['key'])
        bag = fixed.bag_path(case.bench_case(t['key']), keep)
        twins[t['key']] = {**t, 'score': score_clean(json.loads((keep / (bag.name + '.json')).read_text()))}
    return results, twins


def run(cases: list[RandomCase], keep: Path | None, jobs: int = 1, ray_address: str | None = None,
        progress: bool = True, walk_s: float = WALK_S, reuse: bool = False) -> tuple[list[dict], dict]:
    """The twins, then the cases, on the chosen executor; -> (case results in order, twins by key)."""
    from hexapod_locomotion.trials.executor import map_jobs
    firsts = {}
    for c in cases:
        firsts.setdefault(c.twin_key, c)
    k = str(keep) if keep else None
    twins = map_jobs(run_twin, [(c, k, walk_s, reuse) for c in firsts.values()], jobs=jobs, ray_address=ray_address,
                     desc='clean twins', unit='twin', progress=progress)
    by_key = {t['key']: t for t in twins}
    results = map_jobs(run_case, [(c, by_key[c.twin_key], k, walk_s, reuse) for c in cases], jobs=jobs,
                       ray_address=ray_address, desc='random cases', unit='case', progress=progress)
    return results, by_key


# ----------------------------------------------------------------------------- report
def category_table(results: list[dict]) -> str:
    """Per category: cases, right, and the visible cases right."""
    rows: dict[tuple[str, str], list] = {}
    for r in results:
        cats = dict(r['categories'])
        cats['shown'] = ('visible' if r['visible'] else 'invisible',)
        for group, values in cats.items():
            for v in values:
                rows.setdefault((group, v), []).append(r)
    order = ('setting', 'gait', 'terrain', 'cycle', 'class', 'size', 'shown')
    lines = [f'{"category":<26} {"cases":>5} {"right":>5} {"visible":>7} {"visible right":>13}']
    for group in order:
        for (g, v), rs in sorted(rows.items()):
            if g != group:
                continue
            vis = [r for r in rs if r['visible']]
            pct = f'{100 * sum(r["right"] for r in vis) / len(vis):5.0f}%' if vis else '     -'
            lines.append(f'{group + ": " + v:<26} {len(rs):>5} {sum(r["right"] for r in rs):>5} {len(vis):>7} '
                         f'{sum(r["right"] for r in vis):>6} {pct}')
    return '\n'.join(lines)


def case_table(results: list[dict]) -> str:
    lines = []
    for r in results:
        mark = 'right' if r['right'] else 'WRONG'
        lines.append(f'{mark:5} {r["label"]}')
        for row in r['rows']:
            fitted = ('' if row['fitted'] is None else f' fitted {row["fitted"]:.4g}' if not isinstance(row['fitted'], dict)
                      else ' fitted ' + ', '.join(f'{k} {v:.3g}' for k, v in row['fitted'].items()))
            truth = ', '.join(f'{k} {v:.4g}' for k, v in row['truth'].items())
            vis = ','.join(row['visible']) if row['visible'] else 'nowhere'
            lines.append(f'        {row["effect"]} ({truth}) visible on {vis}: {row["verdict"]}{fitted}')
        for f in r['failures']:
            if f.startswith(('misnamed', 'false', 'error')):
                lines.append(f'        {f}')
    return '\n'.join(lines)


def summary(results: list[dict], twins: dict, seconds: float | None) -> str:
    vis = [r for r in results if r['visible']]
    invis = [r for r in results if not r['visible']]
    right_vis = sum(r['right'] for r in vis)
    clean_right = sum(t['score']['right'] for t in twins.values())
    false_twins = sum(len(t['score']['false']) for t in twins.values())
    ool = [row for r in results for row in r['rows'] if row['class'] == 'out-of-list' and row['visible']]
    misnamed = sum(1 for r in results if r['misnamed'])
    by_term = sum(r['how'] == 'term' and r['verdict'] == 'right' for r in ool)
    pct = 100 * right_vis / max(len(vis), 1)
    kinds: dict[str, int] = {}
    for r in results:
        for f in r['failures']:
            kinds[f] = kinds.get(f, 0) + 1
    lines = [
        f'cases: {len(results)} ({len(vis)} visible by the truth, {len(invis)} invisible); clean twins: {len(twins)}',
        f'visible cases right: {right_vis} of {len(vis)} ({pct:.0f}%, goal >= {100 * GOAL_RIGHT:.0f}%): '
        f'{"MET" if pct >= 100 * GOAL_RIGHT else "MISSED"}',
        f'invisible cases right (nothing false claimed): {sum(r["right"] for r in invis)} of {len(invis)}',
        f'all cases right: {sum(r["right"] for r in results)} of {len(results)}',
        f'clean twins with nothing claimed: {clean_right} of {len(twins)} ({false_twins} false claims, goal 0): '
        f'{"MET" if false_twins == 0 else "MISSED"}',
        f'visible out-of-list effects: {len(ool)}, explained by the right term {by_term}, unexplained at the '
        f'right joint {sum(r["how"] == "unexplained" for r in ool)}; cases with a list candidate misnamed: {misnamed}',
        f'wall time {seconds / 60:.1f} min' if seconds is not None else 'wall time: not recorded',
        'failures by kind:' + ('' if kinds else ' none'),
    ]
    lines += [f'  {n:3d}  {k}' for k, n in sorted(kinds.items(), key=lambda kv: (-kv[1], kv[0]))]
    return '\n'.join(lines)


def main(argv=None) -> int:
    from hexapod_locomotion.trials.executor import ExecutorError, JobsInterrupted, add_executor_options
    from hexapod_model import cli_common as cc
    ap = cc.make_parser('random_bench', __doc__.splitlines()[0])
    ap.add_argument('--seed', type=cc.nonnegative_int, default=0, help='draws the cases')
    ap.add_argument('--cases', type=cc.positive_int, default=100, help='number of cases drawn')
    ap.add_argument('--only', type=cc.nonnegative_int, nargs='+', metavar='INDEX',
                    help='run only these cases of the draw (indices as in the report)')
    ap.add_argument('--walk-seconds', type=cc.positive_float, default=WALK_S, help='simulated time of a walk case')
    ap.add_argument('--keep', metavar='DIR', type=cc.output_directory, help='keep the bags and the tool\'s results here')
    ap.add_argument('--json', metavar='OUT.json', type=cc.output_file(('.json',)), help='write the scored results here')
    ap.add_argument('--list', action='store_true', help='print the drawn cases with their truth and exit')
    ap.add_argument('--reuse', action='store_true',
                    help='with --keep DIR: take the bags and results an earlier run of the same seed kept there '
                         '(visibility is judged again); record and analyse only what is missing')
    ap.add_argument('--rescore', metavar='RUN.json', type=cc.existing_file,
                    help='with --keep DIR: score a kept run (its --json output) again, nothing recorded or analysed')
    add_executor_options(ap, 'cases')
    ap.set_defaults(jobs=1)
    cc.add_no_progress_option(ap)
    args = ap.parse_args(argv)
    cases = make_cases(args.seed, args.cases)
    if args.only:
        bad = sorted(i for i in args.only if i >= args.cases)
        if bad:
            ap.error(f'--only {bad[0]}: the draw has cases 0-{args.cases - 1} (see --cases)')
        cases = [cases[i] for i in sorted(set(args.only))]
    if args.list:
        for c in cases:
            print(c.label + '  ' + '; '.join(f'{e.effect} {e.params}' for e in c.effects))
        return 0
    if args.reuse and not args.keep:
        ap.error('--reuse needs --keep DIR (the folder holding the kept bags)')
    if args.rescore:
        if not args.keep:
            ap.error('--rescore needs --keep DIR (the folder holding the run\'s kept results)')
        try:
            run_json = json.loads(Path(args.rescore).read_text())
            results, twins = rescore(run_json, Path(args.keep))
        except (OSError, ValueError, KeyError, TypeError, StopIteration) as exc:
            ap.error(f'--rescore {args.rescore}: not a kept run of this bench in {args.keep} '
                     f'({type(exc).__name__}: {str(exc)[:80]})')
        args.seed, seconds = run_json['seed'], run_json.get('wall_s')
    else:
        t0 = time.perf_counter()
        try:
            results, twins = run(cases, Path(args.keep) if args.keep else None, jobs=args.jobs, ray_address=args.ray,
                                 progress=args.progress, walk_s=args.walk_seconds, reuse=args.reuse)
        except ExecutorError as exc:
            print(f'{ap.prog}: error: {exc}', file=sys.stderr)
            return 1
        except (KeyboardInterrupt, JobsInterrupted):
            return cc.interrupted(ap.prog, f'the finished cases\' bags are in {args.keep}' if args.keep
                                  else 'nothing written')
        seconds = time.perf_counter() - t0
    print(case_table(results))
    print()
    for t in twins.values():
        print(f'{"right" if t["score"]["right"] else "WRONG"} clean {t["key"]}'
              + ''.join(f'\n        false: {f}' for f in t['score']['false']))
    print()
    print(category_table(results))
    print()
    print(summary(results, twins, seconds))
    if args.json:
        out = {'seed': args.seed, 'wall_s': seconds, 'cases': results,
               'twins': [{k: v for k, v in t.items() if k != 'base'} for t in twins.values()]}
        Path(args.json).write_text(json.dumps(out, indent=1, default=_jsonable) + '\n')
    return 0


def _jsonable(x):
    if isinstance(x, np.generic):
        return x.item()
    if isinstance(x, (set, tuple)):
        return list(x)
    return float(x)


if __name__ == '__main__':
    raise SystemExit(main())
