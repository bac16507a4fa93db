"""The sim-vs-real tool on the whole walk: the recorded goals replayed through the MuJoCo hexapod on the
walk's ground (from the bag's /sim/scene) match a clean walk to tick rounding in every phase, stance,
touchdown and lift-off included, and an effect that shows only where a leg carries the body (tibia
backlash, at lift-off) is found there with its size, where the swing-only analysis cannot show it."""
import math

import numpy as np
import pytest

from hexapod_model.description import Effect, load_robot
from hexapod_model.joints import Joint
from hexapod_sim.discrepancy.analysis import analyse
from hexapod_sim.discrepancy.recording import load_recording
from hexapod_sim.discrepancy.report import text_report, to_json
from hexapod_sim.discrepancy.segments import LegPhases, Swing
from hexapod_sim.discrepancy.whole_walk_search import LOADED_PHASES, WHOLE_PHASES, whole_labels
from hexapod_sim.physics.terrain import Ground, TerrainError

TICK_RAD = math.radians(300.0 / 1023.0)
WALK_S = 10.0


def test_touchdown_and_lift_off_are_the_first_tenth_of_a_second_of_stance_and_swing_up():
    ph = LegPhases(swings=(Swing(1.0, 1.2, 1.5, 1.8),), leveling=((2.5, 2.7),))
    t = np.array([0.5, 1.05, 1.15, 1.3, 1.6, 1.85, 1.95, 2.6, 3.0])
    assert [WHOLE_PHASES[i] for i in whole_labels(ph, t)] == [
        'stance', 'lift_off', 'swing_up', 'swing_forward', 'swing_down', 'touchdown', 'stance', 'leveling', 'stance']


def test_the_ground_reads_back_from_its_text_and_bad_text_is_named():
    g = Ground('blocks', 3, (0.45, -0.1))
    assert Ground.from_text(g.to_text()) == g
    for bad in ('', 'terrain: moon', '{terrain: flat, seed: -1}', '{terrain: flat, start_xy_m: [.nan, 0]}', '[1, 2]',
                '{terrain: flat, seed: abc}'):
        with pytest.raises(TerrainError):
            Ground.from_text(bad)


def _walk(tmp_path_factory, name, effects=()):
    """A short tripod calibration walk on flat ground, recorded by the trial runner (with /sim/scene)."""
    import hexapod_locomotion.bench.discrepancy_bench as bench
    from hexapod_locomotion.bench.discrepancy_bench import Case, record_walk
    out = tmp_path_factory.mktemp(name)
    mp = pytest.MonkeyPatch()
    mp.setattr(bench, 'WALK_S', WALK_S)
    try:
        bag, _ = record_walk(Case(name, tuple(effects), walk=('tripod', 'flat')), out)
    finally:
        mp.undo()
    return bag


@pytest.fixture(scope='module')
def robot():
    return load_robot()


@pytest.fixture(scope='module')
def clean(tmp_path_factory, robot):
    bag = _walk(tmp_path_factory, 'clean')
    rec = load_recording(bag, robot)
    return rec, analyse(rec, robot, workers=1)


def test_a_clean_walk_replays_whole_at_tick_rounding_in_every_phase(clean):
    rec, a = clean
    assert rec.ground == Ground('flat', 0, (0.0, 0.0))          # the bag says where it walked
    assert a.mode == 'walk' and a.effects == []
    w = a.whole_walk
    assert w is not None and w.in_step_until_s == pytest.approx(rec.duration_s)
    seen = set()
    for j, row in w.phases.items():
        for ph, v in row.items():
            seen.add(ph)
            assert v.rmse_ticks_nominal <= 0.5, (j, ph, v)
    assert set(LOADED_PHASES) - {'touchdown'} <= seen and 'lift_off' in seen
    doc = to_json(a)
    assert doc['whole_walk']['ground']['terrain'] == 'flat'
    assert set(doc['whole_walk']['phases']['leg1_femur']) >= {'stance', 'lift_off', 'swing_up'}
    assert 'whole walk on the MuJoCo hexapod' in text_report(a)


def test_tibia_backlash_is_found_on_the_whole_walk_with_its_width(tmp_path_factory, robot):
    width = 4.5 * TICK_RAD
    bag = _walk(tmp_path_factory, 'backlash', [Effect('backlash', ('leg2_tibia',), {'width_rad': width})])
    a = analyse(load_recording(bag, robot), robot, workers=1)
    named = [(f.effect.effect, f.effect.joints) for f in a.effects]
    assert named == [('backlash', (Joint(2, 'tibia'),))], text_report(a)
    f = a.effects[0]
    assert f.effect.params['width_rad'] == pytest.approx(width, rel=0.25)
    assert f.condition.startswith('in the whole walk')
    assert f.heldout_rmse_ticks_after < f.heldout_rmse_ticks_before / 1.3
    assert Joint(2, 'tibia') not in a.blind.get('backlash', ())
