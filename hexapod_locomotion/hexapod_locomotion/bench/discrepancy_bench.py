"""Benchmark of the discrepancy tool on concealed data (not a test): ``./hexapod discrepancy-bench``.

Every case injects effects at realistic AX-12A magnitudes into the robot description, runs the
stand calibration routine (:mod:`hexapod_sim.calibration.plan`) on the MuJoCo sim
(:class:`hexapod_sim.physics.plant.HexapodSim`, ``fixed_base=True``), writes the recording as a bag, and
hands the tool only that bag path (the command-line entry point, in process). The tool never
sees the truth or the sim's model. The result is scored against the hidden truth:

* named: every injected effect is reported by name, and nothing else;
* located: the reported joints equal the injected ones (a payload: the same legs); an injected joint
  missing from them counts only if the tool lists it under "cannot show" for that effect and the
  bench confirms with the hidden truth that the recording indeed cannot show it (:func:`score`,
  :func:`unshown_check`); the strict figure without that is printed too;
* parameter error, relative, goal within 25 % (friction, backlash, damping, dead-band) or 10 %
  (saturation, delay, payload);
* held-out improvement: RMS before/after on the effect's joints, goal at least 1.5x;
* false effects on clean recordings: goal none;
* speed: analysis time per minute of recording on this machine, goal under 60 s: wall clock, and the
  CPU time of the analysing process (one core: the figure that holds on a machine shared with other work).

Cases run one after the other by default; ``--jobs N`` runs them in N processes and ``--ray
[ADDRESS]`` as Ray tasks (a local Ray instance, or a running cluster): same cases, same scores.

Cases (magnitudes and joints drawn from ``--seed``): each effect alone on one joint (a payload on
one leg), three effects on a whole leg, three robot-wide, two pairs at once, two clean runs.
``--make-demo DIR`` writes one concealed-effect bag (one leg, < 2 MB) and its truth next to it.

``--set walk`` runs the same kinds of effects (drawn from ``--seed`` + 1000) on 20 s walks of the gait
controller over the MuJoCo terrain instead (:func:`hexapod_locomotion.trials.trial_runner.run_trial`, as
``./hexapod demo``), the three gaits on flat ground and on the blocks in turn, plus a clean walk of
every gait on both; ``--set all`` runs both sets. ``--make-walk-demo DIR`` writes the walk demo bag.
Recording a walk takes most of a case's time: ``--keep DIR --reuse`` analyses the bags kept there again.
``--walk-s 60`` records one-minute walks instead (the speed goal is per minute of walk; keep each length in
its own DIR, as ``--reuse`` finds bags by case name).
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
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml

from hexapod_model.description import JOINT_ROLES, LEGS, Effect, effects_to_overlay, joint_name, load_robot, parse_joint_name
from hexapod_model.joints import Joint, joint_names
from hexapod_sim.calibration.plan import PHASES as CALIBRATION_PHASES
from hexapod_sim.calibration.plan import calibration_plan, run_calibration
from hexapod_sim.discrepancy.effects import BY_NAME

# Realistic AX-12A magnitudes (joint side) for the injected effects.
RANGES = {
    'coulomb_friction': (0.04, 0.10),      # N m extra (nominal 0.060)
    'static_friction': (0.15, 0.35),       # N m break-away
    'viscous_damping': (0.10, 0.30),       # N m s/rad extra (nominal 0.20)
    'backlash': (math.radians(0.8), math.radians(2.0)),
    'torque_saturation': (0.45, 0.90),     # N m (stall 1.5): supply sag or a weak servo
    'compliance_deadband': (1, 3),         # ticks, integer as the AX-12A register
    'readout_delay': (2, 8),               # ms, whole milliseconds (the sim delays by physics steps)
    'mass_error': (0.03, 0.10),            # kg at the foot
    # the servo law (every servo alike)
    'punch': (0.03, 0.15),                 # N m more than the model's 0.047 (register 48: 20-100 more)
    'motor_damping': (1.1, 1.4),           # times the model's 0.20 N m s/rad
    'goal_latency': (1, 2),                # ms, whole firmware ticks (the sim acts on whole physics steps)
}
TOLERANCE = {'coulomb_friction': 0.25, 'static_friction': 0.25, 'viscous_damping': 0.25, 'backlash': 0.25,
             'compliance_deadband': 0.25, 'torque_saturation': 0.10, 'readout_delay': 0.10, 'mass_error': 0.10,
             'punch': 0.25, 'motor_damping': 0.10, 'goal_latency': 0.10}   # motor_damping: of the whole ratio
GOALS = {'right': 0.9, 'ratio': 1.5, 'seconds_per_minute': 60.0}


@dataclass
class Case:
    name: str
    effects: tuple[Effect, ...]
    speed_scale: float = 1.0
    walk: tuple[str, str] | None = None     # (gait, terrain): a walk instead of the stand routine
    cycle: str = 'calibration'              # a walk's gait cycle: one of WALK_CYCLES
    walk_s: float | None = None             # a walk's simulated walking time [s]; None: WALK_S


GAITS = ('tripod', 'tetrapod', 'pentapod')
TERRAINS = ('flat', 'blocks')
WALK_S = 20.0                 # simulated walking time of a walk case
WALK_START_X = {'flat': 0.0, 'blocks': 0.45}   # on the blocks from the first step
# calibration: config/calibration_walk.yaml (Fig. 4 in sequence, unhurried transfer phases), the walk a
# robot is recorded with to name effects; default: the controller's default cycle (overlapped, fast)
WALK_CYCLES = ('calibration', 'default')


def _value(rng, effect: str) -> float:
    lo, hi = RANGES[effect]
    if effect == 'compliance_deadband':
        return float(rng.integers(lo, hi + 1))
    if effect in ('readout_delay', 'goal_latency'):
        return float(rng.integers(lo, hi + 1)) / 1000.0
    return float(rng.uniform(lo, hi))


def _effect(rng, name: str, joints) -> Effect:
    return Effect(name, tuple(joints), {BY_NAME[name].key: _value(rng, name)})


def make_cases(seed: int, legs=LEGS) -> list[Case]:
    rng = np.random.default_rng(seed)
    legs = tuple(legs)
    everything = tuple(joint_name(leg, r) for leg in legs for r in JOINT_ROLES)

    def one_joint():
        return joint_name(int(rng.choice(legs)), str(rng.choice(JOINT_ROLES)))

    def one_leg():
        leg = int(rng.choice(legs))
        return tuple(joint_name(leg, r) for r in JOINT_ROLES)

    cases = []
    for name in (n for n in BY_NAME if not BY_NAME[n].servo_law):
        cases.append(Case(f'{name}@joint' if name != 'mass_error' else 'mass_error@leg',
                          (_effect(rng, name, one_leg() if name == 'mass_error' else (one_joint(),)),)))
    for name in ('backlash', 'static_friction', 'coulomb_friction'):
        cases.append(Case(f'{name}@leg', (_effect(rng, name, one_leg()),)))
    for name in ('readout_delay', 'torque_saturation', 'viscous_damping'):
        cases.append(Case(f'{name}@robot', (_effect(rng, name, everything),)))
    j = one_joint()
    cases.append(Case('backlash@joint+readout_delay@robot',
                      (_effect(rng, 'backlash', (j,)), _effect(rng, 'readout_delay', everything))))
    leg_a = one_leg()
    others = [leg for leg in legs if joint_name(leg, 'coxa') != leg_a[0]] or list(legs)
    j2 = joint_name(int(rng.choice(others)), str(rng.choice(('femur', 'tibia'))))
    cases.append(Case('coulomb_friction@joint+mass_error@leg',
                      (_effect(rng, 'coulomb_friction', (j2,)), _effect(rng, 'mass_error', leg_a))))
    cases.append(Case('servo_law@robot', tuple(_effect(rng, n, everything)
                                               for n in ('punch', 'motor_damping', 'goal_latency'))))
    cases.append(Case('clean', ()))
    cases.append(Case('clean@0.8x', (), speed_scale=0.8))
    return cases


def make_walk_cases(seed: int, cycle: str = 'calibration', walk_s: float | None = None) -> list[Case]:
    """Walk cases: the stand cases' effects and scopes, gaits and terrains in turn, and a clean walk
    of every gait on flat ground and on the blocks; every walk with the gait ``cycle`` (WALK_CYCLES),
    ``walk_s`` long (default WALK_S)."""
    cases = []
    for i, c in enumerate(make_cases(seed + 1000)):
        if not c.effects:
            continue
        gait, terrain = GAITS[i % 3], TERRAINS[(i // 3) % 2]
        cases.append(Case(f'{gait}/{terrain}:{c.name}', c.effects, walk=(gait, terrain), cycle=cycle, walk_s=walk_s))
    for terrain in TERRAINS:
        for gait in GAITS:
            cases.append(Case(f'{gait}/{terrain}:clean', (), walk=(gait, terrain), cycle=cycle, walk_s=walk_s))
    return cases


def bag_path(case: Case, out_dir: Path) -> Path:
    """Where a case's bag is written (and found again by ``--reuse``)."""
    name = case.name.replace('@', '_at_').replace('+', '_and_')
    if case.walk:
        name = 'walk_' + name.replace('/', '_').replace(':', '_')
    return out_dir / name


def calibration_walk() -> dict:
    """The controller's parameters of a calibration walk (``config/calibration_walk.yaml`` of this
    package, the file a robot's walk is recorded with) as TrialConfig fields."""
    from ament_index_python.packages import get_package_share_directory

    from hexapod_locomotion.core.locomotion_params import LocomotionParams
    from hexapod_model.param_schema import check, specs
    path = Path(get_package_share_directory('hexapod_locomotion')) / 'config' / 'calibration_walk.yaml'
    values = yaml.safe_load(path.read_text())['/**']['ros__parameters']
    known = specs(LocomotionParams)
    unknown = sorted(set(values) - set(known))
    if unknown:
        raise ValueError(f'{path}: not a controller parameter: {", ".join(unknown)}')
    for name, value in values.items():
        why = check(known[name], value)
        if why is not None:
            raise ValueError(f'{path}: {name}: {why}')
    return values


def record_walk(case: Case, out_dir: Path, robot=None, duration_s: float = WALK_S,
                seed: int = 0) -> tuple[Path, float]:
    """Walk the MuJoCo hexapod with the case's effects (the gait controller, as ``./hexapod demo``) for
    the case's ``walk_s`` (else ``duration_s``) on the terrain of ``seed``; -> (bag, duration)."""
    from hexapod_locomotion.trials.trial_runner import TrialConfig, run_trial
    gait, terrain = case.walk
    bag = bag_path(case, out_dir)
    if bag.exists():
        shutil.rmtree(bag)
    overlays = ()
    if case.effects:
        ov = out_dir / (bag.name + '.truth.yaml')
        ov.write_text(yaml.safe_dump(effects_to_overlay(case.effects), sort_keys=False))
        overlays = (str(ov),)
    cfg = TrialConfig(gait=gait, terrain=terrain, seed=seed, duration_s=case.walk_s or duration_s, course_end_m=3.0, record=str(bag),
                      start_x_m=WALK_START_X[terrain], overlays=overlays,
                      **(calibration_walk() if case.cycle == 'calibration' else {}))
    with contextlib.redirect_stdout(io.StringIO()):
        run_trial(cfg)
    for ov in overlays:           # the tool only ever sees the bag
        Path(ov).unlink()
    from hexapod_sim.discrepancy.recording import load_recording
    return bag, load_recording(bag, robot or load_robot()).duration_s


def record_case(case: Case, out_dir: Path, legs=LEGS, robot=None, progress: bool = False,
                phases=CALIBRATION_PHASES) -> tuple[Path, float]:
    """Run the calibration routine (its ``phases``) on the MuJoCo sim with the case's effects; write the bag.
    -> (bag, duration)."""
    from hexapod_sim.physics.plant import HexapodSim
    base = robot or load_robot()
    truth = base.with_effects(case.effects)
    plan = calibration_plan(base, legs=legs, phases=phases, speed_scale=case.speed_scale)
    sim = HexapodSim(truth, fixed_base=True)
    sim.reset(joint_angles={joint_name(leg, r): float(plan.goals_rad[0, i])
                            for leg in plan.legs for i, r in enumerate(JOINT_ROLES)})
    rec = run_calibration(sim, plan, progress=progress, robot=base)
    bag = bag_path(case, out_dir)
    if bag.exists():
        shutil.rmtree(bag)
    rec.write_bag(bag)
    return bag, rec.duration_s


def _legs_of(joints) -> set[int]:
    """The legs of ``joints`` (joints or their names)."""
    return {Joint.of(j).leg for j in joints}


def _as_truth_names(found: dict, case: Case) -> dict:
    """A found servo-law term in the truth's words where the truth holds its robot-wide joint-effect twin:
    the free-leg replay cannot tell a readout delay of every joint from a goal latency (both shift the
    response against the goals by one time), nor viscous damping on every joint from the motor damping
    (``b = (ratio - 1) x`` the model's reflected damping). Anything else is returned as it is."""
    twin = {'goal_latency': 'readout_delay', 'motor_damping': 'viscous_damping'}.get(found['effect'])
    truth = next((t for t in case.effects if t.effect == twin and set(joint_names(t.joints)) == set(found['joints'])),
                 None)
    if truth is None:
        return found
    v = next(iter(found['params'].values()))
    if twin == 'viscous_damping':
        v = (v - 1.0) * load_robot().servo.reflected_damping_nms_per_rad
    return {**found, 'effect': twin, 'params': {BY_NAME[twin].key: float(v)}}


def score(case: Case, result: dict, truly_unshown=None) -> dict:
    """Compare the tool's JSON with the hidden truth of ``case``.

    Strictly right: every injected effect named on exactly its joints (a payload: its leg), nothing
    else. Right: the same, except that injected joints the tool reports under ``cannot_show`` for that
    effect may be missing from what it found (nothing found, or found on the other injected joints
    only), provided ``truly_unshown(effect, joints)`` confirms with the hidden truth that the recording
    indeed cannot show it there (:func:`unshown_check`). Without that check no credit is given.
    """
    found = [_as_truth_names(f, case) for f in result['effects']]
    blind = result.get('cannot_show', {})
    rows = []
    matched = set()
    for t in case.effects:
        cand = [i for i, f in enumerate(found) if f['effect'] == t.effect and i not in matched]
        if t.effect == 'mass_error':
            same = [i for i in cand if _legs_of(found[i]['joints']) == _legs_of(t.joints)]
        else:
            same = [i for i in cand if set(found[i]['joints']) == set(joint_names(t.joints))]
        pick = same[0] if same else (cand[0] if cand else None)
        key = BY_NAME[t.effect].key
        row = {'effect': t.effect, 'truth_joints': joint_names(t.joints), 'truth': t.params[key], 'named': pick is not None,
               'located': bool(same), 'fitted': math.nan, 'param_error': math.nan, 'ratio': math.nan,
               'unshown': [], 'credited': False}
        if pick is not None:
            matched.add(pick)
            f = found[pick]
            row['fitted'] = f['params'][key]
            row['param_error'] = abs(f['params'][key] - t.params[key]) / t.params[key]
            row['ratio'] = f['heldout_rmse_ticks_before'] / max(f['heldout_rmse_ticks_after'], 1e-9)
        if not same and truly_unshown is not None:
            got = set(found[pick]['joints']) if pick is not None else set()
            want = {str(j) for j in t.joints if not (t.effect == 'mass_error' and j.role == 'coxa')}
            rest = sorted(want - got)
            if (got <= set(joint_names(t.joints)) and t.effect != 'mass_error' and rest
                    and set(rest) <= set(blind.get(t.effect, ())) and truly_unshown(t, tuple(rest))):
                row['unshown'] = rest
                row['credited'] = True
        row['param_ok'] = bool(row['param_error'] <= TOLERANCE[t.effect])
        rows.append(row)
    false = [f for i, f in enumerate(found) if i not in matched]
    strict = all(r['named'] and r['located'] for r in rows) and not false
    return {'truth': rows, 'false_effects': false, 'right_strict': strict,
            'right': all((r['named'] and r['located']) or r['credited'] for r in rows) and not false}


def unshown_check(bag: Path, robot=None):
    """``truly_unshown(effect, joints)`` for :func:`score`: the bench's own check, with the hidden truth,
    that a recording cannot show ``effect`` (its true magnitude) on ``joints``: added to the nominal
    model over the tool's analysed reads, it changes the prediction of the fitting and of the held-out
    reads too little for the held-out drop the tool demands of any effect on top of tick rounding, or on
    too few held-out reads for its gain (:func:`hexapod_sim.discrepancy.predict.can_confirm` with
    ``either``: both changes too small): no fit judged on those reads could confirm it. The tool never
    runs this; it sees only the bag."""
    from hexapod_sim.discrepancy.analysis import analyse
    from hexapod_sim.discrepancy.predict import Predictor, can_confirm, prediction_change
    from hexapod_sim.discrepancy.recording import load_recording
    state = {}

    def check(effect: Effect, joints) -> bool:
        if not state:
            base = robot or load_robot()
            a = analyse(load_recording(bag, base), base, workers=1)
            pred = Predictor(a.replay, base, workers=1)
            state.update(a=a, pred=pred, p0=pred.predict([], a.replay.joints))
        a, pred = state['a'], state['pred']
        joints = tuple(j for j in map(Joint.of, joints) if j in a.replay.reads)
        if not joints:
            return True           # not analysed at all: nothing of it is shown
        e = Effect(effect.effect, joints, dict(effect.params))
        return not can_confirm(prediction_change(pred, a.split, state['p0'], e), a.min_drop_ticks,
                               a.min_gain_ticks2, either=True)
    return check


def run_case(job: tuple) -> dict:
    """One case, start to score: record its bag, run the tool on the bag, score it (a job of :func:`run`).

    ``job`` = (case, legs, keep dir or None, reuse). Without a keep dir the bag lives in a temporary
    folder of the machine that runs the job and is deleted. With ``reuse`` a bag already kept in the
    keep dir is analysed again instead of being recorded anew (same seed and cases: the same bag).
    """
    from hexapod_sim.discrepancy.cli import main as tool
    from hexapod_sim.discrepancy.recording import load_recording
    case, legs, keep, reuse = job
    work = Path(keep) if keep else Path(tempfile.mkdtemp(prefix='discrepancy_bench_'))
    work.mkdir(parents=True, exist_ok=True)
    try:
        t0 = time.perf_counter()
        bag = bag_path(case, work)
        if reuse and (bag / 'metadata.yaml').exists():
            duration = load_recording(bag, load_robot()).duration_s
        else:
            bag, duration = record_walk(case, work) if case.walk else record_case(case, work, legs=legs)
        t_sim = time.perf_counter() - t0
        js = work / (bag.name + '.json')
        t0, c0 = time.perf_counter(), time.process_time()
        with contextlib.redirect_stdout(io.StringIO()) as text:
            rc = tool([str(bag), '--json', str(js), '--no-progress'])
        (work / (bag.name + '.txt')).write_text(text.getvalue())
        t_tool, cpu_tool = time.perf_counter() - t0, time.process_time() - c0
        if rc != 0:
            raise RuntimeError(f'the tool failed on case {case.name} (exit {rc})')
        s = score(case, json.loads(js.read_text()), truly_unshown=unshown_check(bag))
        s.update(case=case.name, duration_s=duration, sim_s=t_sim, tool_s=t_tool, tool_cpu_s=cpu_tool,
                 s_per_min=t_tool / (duration / 60.0), cpu_s_per_min=cpu_tool / (duration / 60.0), bag_mb=_bag_mb(bag))
        return s
    finally:
        if not keep:
            shutil.rmtree(work, ignore_errors=True)


def run(cases, legs, keep: Path | None, progress: bool = True, jobs: int = 1, ray_address: str | None = None,
        reuse: bool = False) -> list[dict]:
    """Every case (:func:`run_case`) in this process, a process pool (``jobs``) or as Ray tasks;
    results in the order of ``cases``. The timing fields (``sim_s``, ``tool_s``, ``s_per_min``)
    are wall clock (``tool_cpu_s``, ``cpu_s_per_min``: the tool's CPU time in the process that ran it)
    and the bag size (``bag_mb``) varies by a few bytes between runs; the scores
    depend on the cases only."""
    from hexapod_locomotion.trials.executor import map_jobs
    return map_jobs(run_case, [(c, tuple(legs), str(keep) if keep else None, reuse) for c in cases], jobs=jobs,
                    ray_address=ray_address, desc='benchmark cases', unit='case', progress=progress)


def table(results: list[dict]) -> str:
    lines = [f'{"case":40s} {"truth":>48s} {"fitted":>9s} {"err":>6s} {"ratio":>6s} {"named":>5s} {"joints":>6s} '
             f'{"false":>5s} {"s/min":>6s} {"cpu/min":>7s}']
    for r in results:
        rows = r['truth'] or [None]
        for k, t in enumerate(rows):
            name = r['case'] if k == 0 else ''
            false = str(len(r['false_effects'])) if k == 0 else ''
            spm = f'{r["s_per_min"]:6.1f} {r.get("cpu_s_per_min", math.nan):7.1f}' if k == 0 else ''
            if t is None:
                lines.append(f'{name:40s} {"(clean)":>48s} {"":>9s} {"":>6s} {"":>6s} {"":>5s} {"":>6s} {false:>5s} {spm}')
                continue
            scope = (t['truth_joints'][0] if len(t['truth_joints']) == 1 else
                     f'leg {parse_joint_name(t["truth_joints"][0])[0]}' if len(t['truth_joints']) == 3 else
                     f'{len(t["truth_joints"])} joints')
            truth = f'{t["effect"]} {t["truth"]:.4g} on {scope}'
            where = 'yes' if t['located'] else 'unshn' if t.get('credited') else 'NO'
            lines.append(f'{name:40s} {truth:>48s} {t["fitted"]:9.4g} {100 * t["param_error"]:5.1f}% '
                         f'{t["ratio"]:6.2f} {("yes" if t["named"] else "NO"):>5s} '
                         f'{where:>6s} {false:>5s} {spm}')
            if t.get('credited'):
                lines.append(f'{"":40s}   cannot show (confirmed with the truth): {", ".join(t["unshown"])}')
        for f in r['false_effects']:
            lines.append(f'{"":40s}   false: {f["effect"]} on {len(f["joints"])} joint(s) {f["params"]}')
    return '\n'.join(lines)


def summary(results: list[dict]) -> str:
    effect_rows = [t for r in results for t in r['truth']]
    with_truth = [r for r in results if r['truth']]
    clean = [r for r in results if not r['truth']]
    right = sum(r['right'] for r in with_truth) / max(len(with_truth), 1)
    strict = sum(r.get('right_strict', r['right']) for r in with_truth) / max(len(with_truth), 1)
    p_ok = sum(t['param_ok'] for t in effect_rows) / max(len(effect_rows), 1)
    ratio_ok = sum((t['ratio'] >= GOALS['ratio']) for t in effect_rows) / max(len(effect_rows), 1)
    named = [t for t in effect_rows if t['named']]
    p_named = sum(t['param_ok'] for t in named) / max(len(named), 1)
    false_clean = sum(len(r['false_effects']) for r in clean)
    worst = max(r['s_per_min'] for r in results)
    mean = float(np.mean([r['s_per_min'] for r in results]))
    cpu = [r.get('cpu_s_per_min', math.nan) for r in results]

    def met(ok):
        return 'MET' if ok else 'MISSED'
    return '\n'.join([
        f'right effect and joints (no extra effect), strictly: {100 * strict:.0f}% of {len(with_truth)} cases',
        f'right, where joints the tool says a recording cannot show count if the truth confirms it: '
        f'{100 * right:.0f}% of {len(with_truth)} cases (goal >= {100 * GOALS["right"]:.0f}%): '
        f'{met(right >= GOALS["right"])}',
        f'parameters within tolerance (25% friction/backlash/damping/dead-band, 10% saturation/delay/payload): '
        f'{100 * p_ok:.0f}% of {len(effect_rows)} injected effects ({100 * p_named:.0f}% of the {len(named)} found)',
        f'held-out RMS improvement >= {GOALS["ratio"]}x: {100 * ratio_ok:.0f}% of injected effects',
        f'false effects on clean recordings: {false_clean} (goal 0): {met(false_clean == 0)}',
        f'analysis time per minute of recording: mean {mean:.1f} s, worst {worst:.1f} s '
        f'(goal < {GOALS["seconds_per_minute"]:.0f} s): {met(worst < GOALS["seconds_per_minute"])}',
        f'analysis CPU time per minute of recording (one core, the process that analysed it): mean '
        f'{float(np.mean(cpu)):.1f} s, worst {max(cpu):.1f} s (goal < {GOALS["seconds_per_minute"]:.0f} s): '
        f'{met(max(cpu) < GOALS["seconds_per_minute"])}',
    ])


def make_demo(out_dir: Path, seed: int) -> None:
    """One concealed-effect bag for the docs' demo: one leg on the stand, truth in a separate file."""
    rng = np.random.default_rng(seed)
    leg = int(rng.choice(LEGS))
    name = str(rng.choice(['backlash', 'compliance_deadband', 'coulomb_friction', 'viscous_damping']))
    joint = joint_name(leg, str(rng.choice(JOINT_ROLES)))
    case = Case('discrepancy_demo', (_effect(rng, name, (joint,)),))
    out_dir.mkdir(parents=True, exist_ok=True)
    bag, duration = record_case(case, out_dir, legs=(leg,), progress=True)
    _write_demo_truth(bag, case, f'--make-demo {out_dir} --seed {seed}', duration)


def _bag_mb(bag: Path) -> float:
    return sum(f.stat().st_size for f in bag.iterdir()) / 1e6


def _write_demo_truth(bag: Path, case: 'Case', made_with: str, duration_s: float, label: str = 'demo bag') -> None:
    """The hidden truth of a demo bag, beside it in ``<bag>.truth.yaml``, and one line saying so."""
    truth = bag.parent / f'{bag.name}.truth.yaml'
    truth.write_text(f'# Hidden truth of bags/{bag.name} (the discrepancy tool never reads this file).\n'
                     f'# Made by: discrepancy_bench {made_with}\n'
                     + yaml.safe_dump(effects_to_overlay(case.effects), sort_keys=False))
    print(f'{label} {bag} ({duration_s:.1f} s, {_bag_mb(bag):.2f} MB); truth in {truth}')


def make_walk_demo(out_dir: Path, seed: int) -> None:
    """One concealed-effect walk bag (tripod over the blocks) and its truth in a separate file."""
    rng = np.random.default_rng(seed)
    leg = int(rng.choice(LEGS))
    name = str(rng.choice(['mass_error', 'viscous_damping', 'coulomb_friction', 'readout_delay']))
    joints = (tuple(joint_name(leg, r) for r in JOINT_ROLES) if name == 'mass_error'
              else (joint_name(leg, str(rng.choice(('femur', 'tibia')))),))
    case = Case('walk_demo', (_effect(rng, name, joints),), walk=('tripod', 'blocks'))
    final, duration = _record_named_walk(case, out_dir, 'discrepancy_walk_demo')
    _write_demo_truth(final, case, f'--make-walk-demo {out_dir} --seed {seed}', duration, 'walk demo bag')


def make_servo_law_walk(out_dir: Path) -> None:
    """A calibration walk (tripod, flat) of a plant whose servo firmware differs from the model's: 32 more
    punch (register 48 at 64), 15 % more motor damping, goals one firmware tick later; truth beside it."""
    robot = load_robot()
    every = tuple(joint_name(leg, r) for leg in LEGS for r in JOINT_ROLES)
    case = Case('servo_law_walk', (Effect('punch', every, {'extra_punch_nm': robot.servo.punch_nm}),
                                   Effect('motor_damping', every, {'ratio': 1.15}),
                                   Effect('goal_latency', every, {'delay_s': robot.servo.control_period_s})),
                walk=('tripod', 'flat'))
    final, duration = _record_named_walk(case, out_dir, 'servo_law_walk')
    _write_demo_truth(final, case, f'--make-servo-law-walk {out_dir}', duration, 'servo-law walk bag')


def _record_named_walk(case: Case, out_dir: Path, name: str) -> tuple[Path, float]:
    """Record ``case``'s walk into ``out_dir/name`` (a rosbag2 directory named so, files and metadata too)."""
    out_dir.mkdir(parents=True, exist_ok=True)
    bag, duration = record_walk(case, out_dir)
    final = out_dir / name
    if final.exists():
        shutil.rmtree(final)
    bag.rename(final)
    for f in final.iterdir():                 # rosbag2 names its files after the directory
        if f.name.startswith(bag.name):
            f.rename(final / f.name.replace(bag.name, final.name, 1))
    meta = final / 'metadata.yaml'
    meta.write_text(meta.read_text().replace(bag.name, final.name))
    return final, duration


def _parser():
    """The command line of ``discrepancy_bench``."""
    from hexapod_locomotion.trials.executor import add_executor_options
    from hexapod_model.cli_common import (
        add_no_progress_option,
        make_parser,
        nonnegative_int,
        output_directory,
        output_file,
        positive_float,
    )
    ap = make_parser('discrepancy_bench', __doc__.splitlines()[0])
    ap.add_argument('--seed', type=nonnegative_int, default=0, help='draws the magnitudes and joints of the cases')
    ap.add_argument('--cases', nargs='+', metavar='NAME', help='run only these cases (names as in the table)')
    ap.add_argument('--legs', nargs='+', type=int, choices=LEGS, default=list(LEGS), metavar='LEG',
                    help='legs the routine moves (default all)')
    ap.add_argument('--set', choices=('stand', 'walk', 'all'), default='stand',
                    help='stand: the calibration routine on a stand (default); walk: %d s walks of the three gaits '
                         'on flat ground and the blocks; all: both' % WALK_S)
    ap.add_argument('--walk-s', type=positive_float, default=WALK_S, metavar='S',
                    help='simulated walking time of a walk case [s] (default %(default)g; 60: the one-minute walks '
                         'the speed goal is stated for)')
    ap.add_argument('--walk-cycle', choices=WALK_CYCLES, default='calibration',
                    help="the walks' gait cycle: calibration = config/calibration_walk.yaml (the cycle of Fig. 4 in "
                         "sequence, unhurried; what a robot is recorded with to name effects); default = the "
                         "controller's default (overlapped, faster)")
    ap.add_argument('--keep', metavar='DIR', type=output_directory, help='keep the bags and JSON results here')
    ap.add_argument('--reuse', action='store_true',
                    help='with --keep: analyse the bags already kept there again instead of recording them anew '
                         '(recording dominates a walk case; the cases are the same for the same --seed)')
    ap.add_argument('--json', metavar='OUT.json', type=output_file(('.json',)), help='write the scored results here')
    ap.add_argument('--list', action='store_true', help='list the cases (names only, not the truth) and exit')
    ap.add_argument('--make-demo', metavar='DIR', help='write the demo bag and its truth file into DIR and exit')
    add_executor_options(ap, 'cases')
    ap.set_defaults(jobs=1)      # one case at a time unless asked: the s/min figures are per core
    ap.add_argument('--make-walk-demo', metavar='DIR',
                    help='write the walk demo bag (tripod over the blocks, one hidden effect) and its truth into DIR')
    ap.add_argument('--make-servo-law-walk', metavar='DIR',
                    help='write a calibration walk of a plant whose servo law differs from the model\'s (more '
                         'punch and motor damping, later goals) and its truth into DIR')
    add_no_progress_option(ap)
    return ap


def main(argv=None) -> int:
    from hexapod_locomotion.trials.executor import ExecutorError
    from hexapod_model.cli_common import interrupted
    ap = _parser()
    args = ap.parse_args(argv)
    if args.reuse and not args.keep:
        ap.error('--reuse needs --keep DIR (the folder holding the kept bags)')
    if args.make_demo:
        make_demo(Path(args.make_demo), args.seed)
        return 0
    if args.make_walk_demo:
        make_walk_demo(Path(args.make_walk_demo), args.seed)
        return 0
    if args.make_servo_law_walk:
        make_servo_law_walk(Path(args.make_servo_law_walk))
        return 0
    cases = ((make_cases(args.seed, args.legs) if args.set in ('stand', 'all') else [])
             + (make_walk_cases(args.seed, args.walk_cycle, args.walk_s) if args.set in ('walk', 'all') else []))
    if args.list:
        print('\n'.join(c.name for c in cases))
        return 0
    if args.cases:
        unknown = sorted(set(args.cases) - {c.name for c in cases})
        if unknown:
            ap.error(f'unknown case(s) {unknown}; see --list')
        cases = [c for c in cases if c.name in args.cases]
    try:
        results = run(cases, args.legs, Path(args.keep) if args.keep else None, progress=args.progress, jobs=args.jobs,
                      ray_address=args.ray, reuse=args.reuse)
    except ExecutorError as exc:
        print(f'{ap.prog}: error: {exc}', file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        return interrupted(ap.prog, f'the finished cases\' bags and results are in {args.keep}' if args.keep
                           else 'nothing written')
    for label, part in (('stand calibration routine', [r for r, c in zip(results, cases) if not c.walk]),
                        (f'walks ({args.walk_s:g} s; gait/terrain:effect)', [r for r, c in zip(results, cases) if c.walk])):
        if part:
            print(f'{label}:')
            print(table(part))
            print()
            print(summary(part))
            print()
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=2, default=float) + '\n')
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
