"""Benchmark of the discrepancy tool on physics outside its candidate list (not a test).

``./hexapod shell python -m hexapod_locomotion.bench.dictionary_bench [--cases NAME ...]``

Every case puts one piece of physics the candidate list does not hold into the MuJoCo plant, records
the stand calibration routine of one leg (:mod:`hexapod_sim.calibration.plan`, ``fixed_base=True``)
and analyses the recording with the nominal robot (the tool never sees the truth). Most cases inject
a term of the dictionary (:mod:`hexapod_model.dictionary`) through the description; two put physics
into the plant's MJCF instead, in a parameterisation the dictionary does not share: a joint spring of
MuJoCo's own (``stiffness``/``springref``, integrated implicitly) and twice the rotor inertia
(``armature``: a slower motor whose slowness is inertia, not drive or back-EMF). Scored:

* explained: the right term is named on the right joint, its held-out improvement is at least 1.5x
  and its parameters are within the case's tolerance;
* unexplained: nothing is named and the joint is reported unexplained;
* misnamed: a list candidate or a wrong term is named (goal: none);
* clean: a recording without injected physics names nothing.

``--walk``: the cases with a dictionary term (and the clean one) on 20 s tripod calibration walks on flat
ground instead (:func:`hexapod_locomotion.bench.discrepancy_bench.record_walk`).
"""
from __future__ import annotations

import argparse
import dataclasses
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

from hexapod_model.description import ALL_JOINTS, JOINT_ROLES, Effect, joint_name, load_robot
from hexapod_model.joints import joint_names
from hexapod_sim.calibration.plan import calibration_plan, run_calibration
from hexapod_sim.discrepancy import analyse

LEG = 2


@dataclass(frozen=True)
class Case:
    name: str
    truth: Effect | None            # a dictionary term through the description, or None
    mjcf: tuple[str, str] | None    # (attributes, joint) put into the plant's MJCF instead
    expect: str | None              # the term a right answer names (None: nothing)
    joint: str | None
    tolerance: dict                 # parameter -> (value, absolute tolerance)


def _j(role: str) -> str:
    return joint_name(LEG, role)


CASES = (
    Case('spring-tibia', Effect('cable_spring', (_j('tibia'),), {'stiffness_nm_per_rad': 0.3, 'rest_angle_rad': 0.3}),
         None, 'cable_spring', _j('tibia'), {'stiffness_nm_per_rad': (0.3, 0.06), 'rest_angle_rad': (0.3, 0.1)}),
    Case('spring-femur', Effect('cable_spring', (_j('femur'),), {'stiffness_nm_per_rad': 0.5, 'rest_angle_rad': -0.5}),
         None, 'cable_spring', _j('femur'), {'stiffness_nm_per_rad': (0.5, 0.1), 'rest_angle_rad': (-0.5, 0.1)}),
    Case('periodic-femur', Effect('periodic_friction', (_j('femur'),),
                                  {'amplitude_nm': 0.15, 'period_rad': 0.35, 'phase_rad': 1.0}),
         None, 'periodic_friction', _j('femur'), {'amplitude_nm': (0.15, 0.04), 'period_rad': (0.35, 0.035)}),
    Case('load-femur', Effect('load_friction', (_j('femur'),), {'coefficient': 0.3}),
         None, 'load_friction', _j('femur'), {'coefficient': (0.3, 0.075)}),
    Case('supply-sag', Effect('supply_sag', ALL_JOINTS, {'resistance_ohm': 1.5}),
         None, 'supply_sag', None, {'resistance_ohm': (1.5, 0.5)}),
    # a walk draws 10-12 A: 0.15 ohm (a worn pack and thin wires) sags it by about 15 %
    Case('supply-sag-walk', Effect('supply_sag', ALL_JOINTS, {'resistance_ohm': 0.15}),
         None, 'supply_sag', None, {'resistance_ohm': (0.15, 0.05)}),
    Case('weak-femur', Effect('weak_motor', (_j('femur'),), {'torque_scale': 0.6, 'speed_scale': 0.6}),
         None, 'weak_motor', _j('femur'), {'torque_scale': (0.6, 0.1), 'speed_scale': (0.6, 0.15)}),
    Case('mjcf-spring-tibia', None, ('stiffness="0.3" springref="0"', _j('tibia')), 'cable_spring', _j('tibia'),
         {'stiffness_nm_per_rad': (0.3, 0.06), 'rest_angle_rad': (0.0, 0.1)}),
    Case('mjcf-rotor-femur', None, ('armature="0.013"', _j('femur')), 'weak_motor', _j('femur'), {}),
    Case('clean', None, None, None, None, {}),
)


def record(case: Case, robot):
    """The case's stand recording of leg 2 from the MuJoCo plant (with its physics put in)."""
    import hexapod_sim.physics.plant as plant
    truth = robot.with_effects([case.truth]) if case.truth is not None else robot
    orig = plant.build_scene
    if case.mjcf is not None:
        attr, joint = case.mjcf

        def scene(*a, **k):
            sc = orig(*a, **k)
            return dataclasses.replace(sc, xml=sc.xml.replace(f'<joint name="{joint}" class=',
                                                              f'<joint name="{joint}" {attr} class='))
        plant.build_scene = scene
    try:
        plan = calibration_plan(robot, legs=(LEG,))
        sim = plant.HexapodSim(truth, fixed_base=True)
        sim.reset(joint_angles={joint_name(LEG, r): float(plan.goals_rad[0, i]) for i, r in enumerate(JOINT_ROLES)})
        return run_calibration(sim, plan, progress=False)
    finally:
        plant.build_scene = orig


STAND_CASES = tuple(c for c in CASES if c.name != 'supply-sag-walk')
WALK_CASES = tuple(c for c in CASES if c.mjcf is None and c.name != 'supply-sag')


def record_walk(case: Case, robot, out_dir):
    """The case's 20 s tripod calibration walk on flat ground (the gait controller on the MuJoCo terrain,
    as ``./hexapod demo``), with its term put in through the description."""
    from hexapod_locomotion.bench import discrepancy_bench as fixed
    from hexapod_sim.discrepancy.recording import load_recording
    walk = fixed.Case(case.name, (case.truth,) if case.truth is not None else (), walk=('tripod', 'flat'))
    bag, _ = fixed.record_walk(walk, out_dir, robot)
    return load_recording(bag, robot)


def score(case: Case, a) -> dict:
    """Right term / unexplained / misnamed / clean for one case's analysis."""
    named = [(t.effect.effect, tuple(joint_names(t.effect.joints)), dict(t.effect.params), t.heldout_rmse_ticks_before
              / max(t.heldout_rmse_ticks_after, 1e-9)) for t in a.terms]
    lists = [f.effect.effect for f in a.effects]
    unexplained = [str(j) for u in a.unexplained for j in u.joints]
    out = {'case': case.name, 'named': [(n, j[:3] if len(j) > 3 else j, {k: round(v, 3) for k, v in p.items()},
                                         round(r, 2)) for n, j, p, r in named],
           'list': lists, 'unexplained': unexplained, 'verdict': 'misnamed'}
    if case.expect is None:
        out['verdict'] = 'clean' if not named and not lists else 'misnamed'
        return out
    right = [x for x in named if x[0] == case.expect and (case.joint is None or case.joint in x[1])]
    wrong = [x for x in named if x not in right] or lists
    if right and not wrong:
        n, j, p, ratio = right[0]
        ok = ratio >= 1.5 and all(abs(p[k] - v) <= tol for k, (v, tol) in case.tolerance.items())
        out['verdict'] = 'explained' if ok else 'right term, off value'
    elif not named and not lists and unexplained:
        out['verdict'] = 'unexplained'
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--cases', nargs='*', choices=[c.name for c in CASES],
                    help='default: every case of the set (stand or --walk)')
    ap.add_argument('--walk', action='store_true', help='tripod calibration walks on flat ground instead of stands '
                                                         '(the cases with a dictionary term, and the clean one)')
    args = ap.parse_args(argv)
    robot = load_robot()
    counts: dict[str, int] = {}
    tmp = tempfile.TemporaryDirectory()
    for case in (c for c in (WALK_CASES if args.walk else STAND_CASES) if args.cases is None or c.name in args.cases):
        t0 = time.perf_counter()
        rec = record_walk(case, robot, Path(tmp.name)) if args.walk else record(case, robot)
        t1 = time.perf_counter()
        a = analyse(rec, robot, workers=1)
        r = score(case, a)
        counts[r['verdict']] = counts.get(r['verdict'], 0) + 1
        print(f"{r['case']:<18} {r['verdict']:<22} named={r['named']} list={r['list']} "
              f"unexplained={r['unexplained']} (record {t1 - t0:.0f} s, analyse {time.perf_counter() - t1:.0f} s)",
              flush=True)
    print('summary: ' + ', '.join(f'{k} {v}' for k, v in sorted(counts.items())))
    return 0 if counts.get('misnamed', 0) == 0 else 1


if __name__ == '__main__':
    raise SystemExit(main())
