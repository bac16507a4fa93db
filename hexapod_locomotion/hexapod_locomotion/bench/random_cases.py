"""The random bench's cases (:mod:`~hexapod_locomotion.bench.random_bench`): a seeded generator of
concealed-effect cases, each drawn from its own generator (case ``index`` of ``seed`` is the same whatever
the number drawn), the categories the bench's table counts them in, and the truth of what a recording
shows (the visibility of each effect, per joint and phase). What is drawn and in which
shares is described in :mod:`~hexapod_locomotion.bench.random_bench`.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from hexapod_locomotion.bench import dictionary_bench
from hexapod_locomotion.bench import discrepancy_bench as fixed
from hexapod_model.description import ALL_JOINTS, JOINT_ROLES, LEGS, Effect, joint_name, load_robot, parse_joint_name
from hexapod_model.dictionary import BY_TERM
from hexapod_model.joints import Joint, joint_names
from hexapod_sim.calibration.plan import PHASES as CALIBRATION_PHASES
from hexapod_sim.discrepancy.effects import BY_NAME

IN_LIST = tuple(n for n in BY_NAME if not BY_NAME[n].servo_law)
SERVO_LAW = tuple(n for n in BY_NAME if BY_NAME[n].servo_law)
# out-of-list term -> the dictionary_bench case its magnitudes and tolerances are drawn around, per joint role
OUT_OF_LIST = {
    'cable_spring': {'femur': 'spring-femur', 'tibia': 'spring-tibia'},
    'periodic_friction': {'femur': 'periodic-femur', 'tibia': 'periodic-femur'},
    'load_friction': {'femur': 'load-femur', 'tibia': 'load-femur'},
    'weak_motor': {'femur': 'weak-femur', 'tibia': 'weak-femur'},
    'supply_sag': {'robot': 'supply-sag-walk'},      # walks only: a one-leg stand lacks the other servos' current
}
ANGLES = ('rest_angle_rad', 'phase_rad')  # drawn around the case's value by +-ANGLE_SPREAD, judged absolutely
SCALE_SPREAD = (0.75, 1.25)               # the other term parameters: the case's value times this
ANGLE_SPREAD = 0.2                        # [rad]
CLASSES = ('in-list', 'out-of-list', 'servo-law')
CLASS_SHARE = (0.5, 0.25, 0.25)
SCOPE_SHARE = {'joint': 0.5, 'leg': 0.25, 'robot': 0.25}     # in-list effects other than a payload
WALK_SHARE = 0.55
PAIR_SHARE = 0.4
BLOCK_SEEDS = (0, 1, 2)
VISIBLE_MARGIN_TICKS = 0.5    # RMS above the baseline in one joint and phase that makes an effect visible
MIN_PHASE_READS = 20          # reads a joint needs in a phase for that phase to count


@dataclass(frozen=True)
class RandomCase:
    """One drawn case: its effects (with their class), and the stand routine's leg or the walk."""

    index: int
    effects: tuple[Effect, ...]
    classes: tuple[str, ...]                 # one of CLASSES per effect
    leg: int = 1                             # stand: the leg the routine moves
    walk: tuple[str, str] | None = None      # (gait, terrain)
    cycle: str = 'calibration'               # a walk's gait cycle (discrepancy_bench.WALK_CYCLES)
    terrain_seed: int = 0
    tolerance: tuple = field(default=())     # per effect: {param: (relative or absolute tolerance, 'rel'|'abs')}
    phases: tuple[str, ...] = CALIBRATION_PHASES   # stand: the routine's phases (all of them in a drawn case)

    @property
    def setting(self) -> str:
        return 'walk' if self.walk else 'stand'

    @property
    def twin_key(self) -> str:
        if self.walk:
            return f'twin_{self.walk[0]}_{self.walk[1]}{self.terrain_seed}_{self.cycle}'
        return f'twin_stand_leg{self.leg}' + ('' if self.phases == CALIBRATION_PHASES else '_' + '_'.join(self.phases))

    @property
    def label(self) -> str:
        parts = [_effect_label(e) for e in self.effects]
        where = (f'{self.walk[0]}/{self.walk[1]}{self.terrain_seed if self.walk[1] != "flat" else ""}/{self.cycle}'
                 if self.walk else f'stand/leg{self.leg}')
        return f'{self.index:03d} {where}:' + '+'.join(parts)

    def bench_case(self, name: str, effects=None) -> fixed.Case:
        """The fixed bench's case (what its recording functions take) of this one, with ``effects``."""
        return fixed.Case(name, tuple(self.effects if effects is None else effects), walk=self.walk,
                          cycle=self.cycle)

    def without(self, k: int) -> tuple[Effect, ...]:
        """The case's effects but its ``k``-th."""
        return tuple(e for i, e in enumerate(self.effects) if i != k)


def scope_label(joints) -> str:
    """'robot', 'leg3' or the joints' names (``joints``: joints or their names)."""
    if len(joints) == len(ALL_JOINTS):
        return 'robot'
    if len(joints) == 3 and len(legs_of(joints)) == 1:
        return f'leg{Joint.of(joints[0]).leg}'
    return ','.join(joint_names(joints))


def _effect_label(e: Effect) -> str:
    return f'{e.effect}@{scope_label(e.joints)}'


def legs_of(joints) -> set[int]:
    """The legs of ``joints`` (joints or their names)."""
    return {Joint.of(j).leg for j in joints}


def _leg_joints(leg: int) -> tuple[str, ...]:
    return tuple(joint_name(leg, r) for r in JOINT_ROLES)


def _draw_term(rng, name: str, joints) -> tuple[Effect, dict]:
    """An out-of-list term on ``joints``, drawn around its dictionary_bench case; its tolerances."""
    role = 'robot' if BY_TERM[name].robot_wide else parse_joint_name(joints[0])[1]
    case = next(c for c in dictionary_bench.CASES if c.name == OUT_OF_LIST[name][role])
    params, tol = {}, {}
    for key, v in case.truth.params.items():
        if key in ANGLES:
            params[key] = float(v + rng.uniform(-ANGLE_SPREAD, ANGLE_SPREAD))
        else:
            params[key] = float(v * rng.uniform(*SCALE_SPREAD))
        if key in case.tolerance:
            ref, t = case.tolerance[key]
            tol[key] = (t, 'abs') if key in ANGLES else (t / abs(ref), 'rel')
    return Effect(name, tuple(joints), params), tol


def _draw_one(rng, cls: str, walk: bool, leg: int, taken: set, robot_wide_ok: bool):
    """One effect of class ``cls`` whose joints avoid ``taken`` (on ``leg`` for a stand); None if none fits."""
    free_legs = [lg for lg in LEGS if not set(_leg_joints(lg)) & taken]

    def pick_leg():
        if not walk:
            return leg if not set(_leg_joints(leg)) & taken else None
        return int(rng.choice(free_legs)) if free_legs else None

    def pick_joint(roles=JOINT_ROLES):
        legs = [leg] if not walk else list(LEGS)
        options = [joint_name(lg, r) for lg in legs for r in roles if joint_name(lg, r) not in taken]
        return str(rng.choice(options)) if options else None

    if cls == 'servo-law':
        if not robot_wide_ok:
            return None
        name = str(rng.choice(SERVO_LAW))
        return fixed._effect(rng, name, ALL_JOINTS), {}
    if cls == 'out-of-list':
        names = [n for n in OUT_OF_LIST if walk or not BY_TERM[n].robot_wide]
        name = str(rng.choice(names))
        if BY_TERM[name].robot_wide:
            return _draw_term(rng, name, ALL_JOINTS) if robot_wide_ok else None
        j = pick_joint(('femur', 'tibia'))
        return _draw_term(rng, name, (j,)) if j else None
    name = str(rng.choice(IN_LIST))
    scope = 'leg' if name == 'mass_error' else str(rng.choice(list(SCOPE_SHARE), p=list(SCOPE_SHARE.values())))
    if scope == 'robot':
        return (fixed._effect(rng, name, ALL_JOINTS), {}) if robot_wide_ok else None
    if scope == 'leg':
        lg = pick_leg()
        return (fixed._effect(rng, name, _leg_joints(lg)), {}) if lg is not None else None
    j = pick_joint()
    return (fixed._effect(rng, name, (j,)), {}) if j else None


def draw_case(seed: int, index: int) -> RandomCase:
    """Case ``index`` of ``seed`` (its own generator: the same case whatever the number drawn)."""
    rng = np.random.default_rng((seed, index))
    walk = bool(rng.random() < WALK_SHARE)
    leg = int(rng.choice(LEGS))
    gait = str(rng.choice(fixed.GAITS))
    terrain = str(rng.choice(fixed.TERRAINS))
    cycle = str(rng.choice(fixed.WALK_CYCLES))
    terrain_seed = int(rng.choice(BLOCK_SEEDS)) if terrain != 'flat' else 0
    n = 2 if rng.random() < PAIR_SHARE else 1
    effects, classes, tols = [], [], []
    taken: set = set()
    while len(effects) < n:
        cls = str(rng.choice(CLASSES, p=CLASS_SHARE))
        robot_wide_ok = not any(len(e.joints) == len(ALL_JOINTS) for e in effects)
        got = _draw_one(rng, cls, walk, leg, taken, robot_wide_ok)
        if got is None or any(e.effect == got[0].effect for e in effects):
            continue
        e, tol = got
        effects.append(e)
        classes.append(cls)
        tols.append(tol)
        if len(e.joints) < len(ALL_JOINTS):
            taken |= set(joint_names(e.joints))       # the draw picks among names
    return RandomCase(index, tuple(effects), tuple(classes), leg=leg,
                      walk=(gait, terrain) if walk else None, cycle=cycle if walk else 'calibration',
                      terrain_seed=terrain_seed if walk else 0, tolerance=tuple(tols))


def make_cases(seed: int, count: int) -> list[RandomCase]:
    return [draw_case(seed, i) for i in range(count)]


def categories(case: RandomCase) -> dict[str, tuple[str, ...]]:
    """The per-category table's rows a case counts in (a pair counts in the class of each effect)."""
    return {'setting': (case.setting,),
            'gait': (case.walk[0],) if case.walk else ('stand',),
            'terrain': (case.walk[1],) if case.walk else ('stand',),
            'cycle': (case.cycle,) if case.walk else ('stand',),
            'class': tuple(sorted(set(case.classes))),
            'size': ('single' if len(case.effects) == 1 else 'pair',)}


# ----------------------------------------------------------------------------- visibility
def phase_rms(residual: dict, labels: dict, names) -> dict:
    """Per joint name (the tool's JSON's words) and phase: (RMS of the residual [ticks], reads). ``labels``:
    phase index per read (negative: not judged); ``names``: the phases' names by index. ``'*'``: every
    judged read."""
    out = {}
    for j, r in residual.items():
        lab = np.asarray(labels[j])
        r = np.asarray(r, dtype=float)
        row = {}
        judged = lab >= 0
        if np.any(judged):
            row['*'] = (float(np.sqrt(np.mean(r[judged] ** 2))), int(np.count_nonzero(judged)))
        for k, name in enumerate(names):
            sel = lab == k
            if np.any(sel):
                row[name] = (float(np.sqrt(np.mean(r[sel] ** 2))), int(np.count_nonzero(sel)))
        out[str(j)] = row
    return out


def visible_joints(case_rms: dict, base_rms: dict | None, margin: float = VISIBLE_MARGIN_TICKS,
                   min_reads: int = MIN_PHASE_READS) -> dict[str, list[tuple[str, float]]]:
    """Joints on which the residual departs from the baseline: joint -> [(phase, excess RMS)] of every
    phase with at least ``min_reads`` reads whose RMS exceeds the baseline's in that joint and phase
    (the joint's whole baseline where the twin has no such phase; none: 0) by more than ``margin``."""
    out = {}
    for j, row in case_rms.items():
        base = (base_rms or {}).get(j, {})
        hits = []
        for ph, (rms, n) in row.items():
            if ph == '*' or n < min_reads:
                continue
            ref = base.get(ph, base.get('*', (0.0, 0)))[0]
            if rms > ref + margin:
                hits.append((ph, round(rms - ref, 3)))
        if hits:
            out[j] = hits
    return out


def stand_labels(rec, legs, phases=CALIBRATION_PHASES) -> tuple[dict, tuple[str, ...]]:
    """Phase index of every read of a stand recording (the routine's phases; the settling excluded)."""
    from hexapod_sim.calibration.plan import calibration_plan
    plan = calibration_plan(load_robot(), legs=legs, phases=phases)
    names = tuple(p.name for p in plan.phases)
    out = {}
    for j, s in rec.states.items():
        lab = np.full(len(s.t_s), -1)
        for k, p in enumerate(plan.phases):
            if p.name != 'settle':
                lab[(s.t_s >= p.t_start_s) & (s.t_s < p.t_end_s)] = k
        out[j] = lab
    return out, names


def stand_residual(rec, other) -> dict[str, np.ndarray]:
    """Reads of ``rec`` minus those of ``other`` (the same routine) at ``rec``'s stamps [ticks]."""
    from hexapod_model.servo import theta_to_tick
    servo = load_robot().servo
    out = {}
    for j, s in rec.states.items():
        o = other.states.get(j)
        if o is None or len(o.t_s) < 2:
            continue
        out[j] = (theta_to_tick(s.theta_rad, servo).astype(float)
                  - np.interp(s.t_s, o.t_s, theta_to_tick(o.theta_rad, servo).astype(float)))
    return out


def walk_phase_rms(rec, robot) -> dict:
    """Per joint and whole-walk phase: the RMS of the recording against the open-loop replay of its own
    goals through ``robot`` on its ground (reads from ``whole_walk_search.START_S`` on)."""
    from hexapod_sim.discrepancy.segments import gait_phases
    from hexapod_sim.discrepancy.whole_walk import rec_ticks, replay_walk
    from hexapod_sim.discrepancy.whole_walk_search import START_S, WHOLE_PHASES, whole_labels
    from hexapod_sim.physics.terrain import Ground
    nominal = load_robot()
    pred = replay_walk(rec, robot, rec.ground or Ground())
    phases = gait_phases(rec, LEGS)
    residual, labels = {}, {}
    for j, p in pred.items():
        t = rec.states[j].t_s[:len(p)]
        residual[j] = rec_ticks(rec, nominal, j)[:len(p)].astype(float) - p
        lab = whole_labels(phases[j.leg], t)
        labels[j] = np.where(t >= START_S, lab, -1)
    return phase_rms(residual, labels, WHOLE_PHASES)
