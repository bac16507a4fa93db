"""Terrain classification: gait-cycle features from the streams (the same from a bag as in process),
label files, the model file and its version check, and the command line's bad-input lines."""
import gzip
import pickle
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from hexapod_locomotion.core.terrain_features import FEATURE_NAMES
from hexapod_locomotion.core.terrain_model import DEFAULT_MODEL, TerrainModel, TerrainModelError
from hexapod_locomotion.trials import terrain_cli
from hexapod_locomotion.trials.terrain_data import StreamTap, TerrainDataError, bag_cycles, labels_path, read_labels, replay, truth_labels
from hexapod_locomotion.trials.trial_runner import TrialConfig, run_trial
from hexapod_model.description import load_robot

ROOT = Path(__file__).resolve().parents[2]
CLASSES = ('flat', 'rough', 'blocks', 'soft', 'slippery')


@pytest.fixture(scope='module')
def soft_walk(tmp_path_factory):
    """A short tripod walk on soft ground, recorded to a bag and tapped in process (the same seed)."""
    bag = tmp_path_factory.mktemp('terrain') / 'soft_walk'
    cfg = TrialConfig(gait='tripod', terrain='class_soft', seed=3, duration_s=9.0)
    run_trial(TrialConfig(**{**cfg.__dict__, 'record': str(bag)}))
    tap = StreamTap()
    run_trial(cfg, recorder=tap)
    return bag, tap


def test_cycles_from_a_bag_equal_those_in_process(soft_walk):
    bag, tap = soft_walk
    robot = load_robot()
    live = replay(robot, tap.events)
    labels_path(bag).write_text('0 1000 soft\n')
    from_bag = bag_cycles(bag, robot, CLASSES)
    assert len(live) >= 3                    # tripod: a cycle is two phases of about 1 s
    assert len(from_bag['labels']) == len(live)
    for c in live:
        assert c.values.shape == (len(FEATURE_NAMES),)
        assert c.t_end_s > c.t_start_s
    np.testing.assert_allclose(from_bag['X'], np.array([c.values for c in live]), rtol=1e-6, atol=1e-6)
    assert from_bag['labels'] == ['soft'] * len(live)
    # every cycle of a walk on one class takes its label from the sim truth
    assert {lab for *_, lab in truth_labels('class_soft', 3, tap.events)} == {'soft'}


def test_label_files(tmp_path):
    f = tmp_path / 'a.labels.txt'
    f.write_text('# comment\n0 10 flat\n10 12 -  # across the boundary\n12 30.5 soft\n')
    assert read_labels(f, CLASSES) == [(0.0, 10.0, 'flat'), (10.0, 12.0, '-'), (12.0, 30.5, 'soft')]
    f.write_text('0 10 flat\n10 20 gravel\n')
    with pytest.raises(TerrainDataError, match=r"a.labels.txt:2: unknown label 'gravel'; known: flat, rough"):
        read_labels(f, CLASSES)
    f.write_text('0 ten flat\n')
    with pytest.raises(TerrainDataError, match='a.labels.txt:1: START_S and END_S must be numbers'):
        read_labels(f, CLASSES)
    f.write_text('5 1 flat\n')
    with pytest.raises(TerrainDataError, match='START_S < END_S'):
        read_labels(f, CLASSES)


def test_model_round_trip_and_version_check(tmp_path):
    rng = np.random.default_rng(0)
    x = rng.normal(size=(60, len(FEATURE_NAMES)))
    y = np.where(x[:, 0] > 0, 'flat', 'soft')
    model = TerrainModel.fit(x, y, {'command': 'test'})
    path = model.save(tmp_path / 'm.pkl.gz')
    back = TerrainModel.load(path)
    assert back.classes == ('flat', 'soft') and back.provenance['cycles_per_class'] == model.provenance['cycles_per_class']
    np.testing.assert_array_equal(back.predict(x)[0], model.predict(x)[0])
    data = pickle.loads(gzip.decompress(path.read_bytes()))
    data['features_version'] = 0
    path.write_bytes(gzip.compress(pickle.dumps(data)))
    with pytest.raises(TerrainModelError, match='made for terrain features version 0'):
        TerrainModel.load(path)
    data['features_version'], data['sklearn_version'] = pickle.loads(gzip.decompress(model.save(
        tmp_path / 'n.pkl.gz').read_bytes()))['features_version'], '0.1'
    path.write_bytes(gzip.compress(pickle.dumps(data)))
    with pytest.raises(TerrainModelError, match="made with scikit-learn '0.1'"):
        TerrainModel.load(path)
    path.write_bytes(b'not a pickle')
    with pytest.raises(TerrainModelError, match='not a terrain model file'):
        TerrainModel.load(path)


def test_the_packaged_model_carries_its_provenance():
    model = TerrainModel.load(DEFAULT_MODEL)
    assert set(model.classes) == set(CLASSES)
    p = model.provenance
    assert p['command'].startswith('./hexapod terrain train') and p['code_version'] not in ('', 'unknown')
    assert any('seed' in t for s in p['sources'] for t in s.get('trials', ()))


def _cli(*args):
    return subprocess.run([sys.executable, '-m', 'hexapod_locomotion.trials.terrain_cli', *args], capture_output=True,
                          text=True, timeout=300)


def test_bad_input_is_one_line_and_exit_2(tmp_path):
    old = tmp_path / 'old.pkl.gz'
    data = pickle.loads(gzip.decompress(DEFAULT_MODEL.read_bytes()))
    data['features_version'] = -1
    old.write_bytes(gzip.compress(pickle.dumps(data)))
    r = _cli('evaluate', '--model', str(old), '--set', 'test')
    assert r.returncode == 2 and r.stdout == ''
    assert r.stderr.strip().count('\n') == 0 and 'made for terrain features version -1' in r.stderr
    # a bag without the controller's streams (the calibration stand's)
    r = _cli('train', str(ROOT / 'bags' / 'discrepancy_demo'), '--out', str(tmp_path / 'x.pkl.gz'))
    assert r.returncode == 2 and r.stderr.strip().count('\n') == 0
    assert 'no /ground_detection, /swing_down in the bag' in r.stderr
    assert not (tmp_path / 'x.pkl.gz').exists()
    r = _cli('evaluate', '--set', 'nonsense')
    assert r.returncode == 2 and "unknown set 'nonsense'" in r.stderr


def test_analyse_confusion_against_labels_and_an_unknown_label(soft_walk, tmp_path):
    from hexapod_locomotion.trials import analyse
    bag, _ = soft_walk
    good = tmp_path / 'good.txt'
    good.write_text('0 1000 soft\n')
    r = subprocess.run([sys.executable, '-m', 'hexapod_locomotion.trials.analyse', str(bag), '--labels', str(good)],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    assert 'terrain (classed offline by' in r.stdout and 'against good.txt:' in r.stdout
    assert '| soft |' in r.stdout
    bad = tmp_path / 'bad.txt'
    bad.write_text('0 1000 grass\n')
    r = subprocess.run([sys.executable, '-m', 'hexapod_locomotion.trials.analyse', str(bag), '--labels', str(bad)],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 2 and "bad.txt:1: unknown label 'grass'" in r.stderr
    assert analyse is not None and terrain_cli is not None


def _two_class_rows(rng, n, shift):
    """Rows of 2 cycle features and 6 leg blocks (nominal x, two features), every block of one class."""
    xs = np.array([225.0, 225.0, -225.0, -225.0, 0.0, 0.0])
    legs = [np.c_[np.full(n, x), rng.normal(shift, 1.0, size=(n, 2))] for x in xs]
    return np.c_[rng.normal(shift, 1.0, size=(n, 2)), *legs]


def test_the_front_legs_weigh_more_and_a_crossing_switches_the_class():
    from hexapod_locomotion.core.terrain_estimator import CycleLegClassifier
    rng = np.random.default_rng(1)
    a, b = _two_class_rows(rng, 80, 0.0), _two_class_rows(rng, 80, 4.0)
    x, y = np.r_[a, b], np.array(['a'] * 80 + ['b'] * 80)
    est = CycleLegClassifier(2, 3, cycle_weight=0.25, front_weight=3.0, tree_params={'max_iter': 30}).fit(x, y)
    w = est.leg_weights(x[:1])[0]
    np.testing.assert_allclose(w / w[4], [3, 3, 1 / 3, 1 / 3, 1, 1])
    assert (est.predict(a) == 'a').mean() > 0.95 and (est.predict(b) == 'b').mean() > 0.95
    # the front and middle legs on class b, the rear legs and the whole cycle's features still a
    crossing = a[:20].copy()
    for leg in (0, 1, 4, 5):
        crossing[:, 2 + 3 * leg:5 + 3 * leg] = b[:20, 2 + 3 * leg:5 + 3 * leg]
    assert (est.predict(crossing) == 'b').mean() > 0.9
    p = est.predict_proba(crossing)
    np.testing.assert_allclose(p.sum(axis=1), 1.0)
    # with the legs weighed alike and the cycle model at full weight the same rows stay a
    even = CycleLegClassifier(2, 3, cycle_weight=1.0, front_weight=1.0, tree_params={'max_iter': 30}).fit(x, y)
    assert (even.predict(crossing) == 'a').mean() > 0.5


def test_with_leg_context_a_leg_is_classed_against_the_posture_of_the_whole_cycle():
    """A leg's feature tells its class only against a cycle feature (a foot's contact height against how
    low the body stands): the leg model alone cannot tell, with the cycle's features beside it it can."""
    from hexapod_locomotion.core.terrain_estimator import CycleLegClassifier
    rng = np.random.default_rng(3)
    n = 400
    posture = rng.uniform(-5.0, 5.0, size=n)
    y = np.where(rng.random(n) < 0.5, 'a', 'b')
    cyc = np.c_[posture, rng.normal(size=n)]                  # the cycle model: no clue to the class
    leg = posture + np.where(y == 'a', -0.5, 0.5)             # the leg's feature: relative to the posture
    xs = np.array([225.0, 225.0, -225.0, -225.0, 0.0, 0.0])
    x = np.c_[cyc, *[np.c_[np.full(n, fx), leg + rng.normal(0, 0.05, n)] for fx in xs]]
    tr, te = slice(0, 300), slice(300, n)
    alone = CycleLegClassifier(2, 2, cycle_weight=0.1, tree_params={'max_iter': 40}).fit(x[tr], y[tr])
    ctx = CycleLegClassifier(2, 2, cycle_weight=0.1, tree_params={'max_iter': 40}, leg_context=[0]).fit(x[tr], y[tr])
    assert ctx._leg_rows(x[:2]).shape == (12, 3)
    assert (ctx.predict(x[te]) == y[te]).mean() > 0.9
    assert (alone.predict(x[te]) == y[te]).mean() < 0.8


def test_the_temperature_fitted_on_held_out_scores_calibrates_them():
    from hexapod_locomotion.core.terrain_estimator import fit_temperature, softmax
    rng = np.random.default_rng(2)
    scores = rng.normal(0.0, 4.0, size=(4000, 5))
    truth = np.array([rng.choice(5, p=p) for p in softmax(scores / 2.0)])      # drawn at temperature 2
    assert 1.7 < fit_temperature(scores, truth) < 2.4
    sharp = np.array([rng.choice(5, p=p) for p in softmax(scores / 0.5)])
    assert 0.4 < fit_temperature(scores, sharp) < 0.6


def test_each_leg_takes_the_class_under_its_foot_on_a_course():
    from types import SimpleNamespace

    from hexapod_locomotion.trials.terrain_data import leg_labels
    from hexapod_sim.physics.terrain_classes import layout
    segs = layout('course', 20)
    edge = segs[0].x1_m
    events = [('x', t, edge - 0.5 + 0.05 * t) for t in np.arange(0.0, 20.0, 0.1)]      # 0.05 m/s
    at = SimpleNamespace(t_start_s=9.0, t_end_s=11.0)                                 # the trunk crosses at 10 s
    before = SimpleNamespace(t_start_s=0.0, t_end_s=2.0)                             # every foot on the first class
    got = leg_labels('course', 20, events, [at, before], load_robot())
    first, second = segs[0].label, segs[1].label
    # legs 1, 2 front (0.225 m ahead of the trunk), 3, 4 rear, 5, 6 middle: on the boundary
    assert got[0] == (second, second, first, first, '-', '-')
    assert got[1] == (first,) * 6


def _swing_step_mm(body_drop_m: float, foot_above_m: float) -> float:
    """Leg 1's swing-down step feature of one synthetic tripod cycle: every commanded foot of the
    stance ``body_drop_m`` higher in the body frame (the body sank that much), leg 1 stopping with its
    foot ``foot_above_m`` above the others."""
    from hexapod_locomotion.core.terrain_features import CycleFeatureExtractor
    from hexapod_model.description import JOINT_ROLES, LEGS, joint_name
    from hexapod_model.kinematics import inverse, stance_feet
    from hexapod_model.servo import theta_to_tick
    robot = load_robot()
    feet = stance_feet(robot) + [0.0, 0.0, body_drop_m]
    angles = {leg: inverse(robot, leg, feet[i]) for i, leg in enumerate(LEGS)}
    ex = CycleFeatureExtractor(robot)
    ex.command([joint_name(leg, r) for leg in LEGS for r in JOINT_ROLES],
               [float(a) for leg in LEGS for a in angles[leg]])
    for t, group in enumerate(((1, 4, 5), (2, 3, 6), (1, 4, 5))):
        ends = [inverse(robot, leg, feet[LEGS.index(leg)] + [0.0, 0.0, foot_above_m if leg == 1 else 0.0])
                for leg in group]
        msg = {'legs': list(group), 't_des_s': 1.0, 'coxa_rad': [e[0] for e in ends],
               'femur_init_rad': [e[1] for e in ends], 'femur_fin_rad': [e[1] for e in ends],
               'tibia_init_rad': [e[2] for e in ends], 'tibia_fin_rad': [e[2] for e in ends]}
        cycle = ex.swing_start(float(t), msg)
        if cycle is not None:
            return float(cycle.values[FEATURE_NAMES.index('leg1_contact_step_mm')])
        for leg, end in zip(group, ends):
            tick = float(theta_to_tick(end[1], robot.servo))
            for k, stop in enumerate((False, False, True)):
                ex.detection({'leg': leg, 't_swing_s': 0.2 * (k + 1), 'theta_des_tick': tick, 'theta_real_tick': tick,
                              'err_tick': 1.0 + 4.0 * k, 'err_est_tick': 1.0, 'threshold_tick': 3.0,
                              'stopped': stop, 'stop_reason': 1 if stop else 0})
    raise AssertionError('the cycle did not close')


def test_a_swing_down_step_is_measured_against_the_other_feet_not_the_nominal_ground():
    """After soft or slippery ground the body stands lower or tilted for a few cycles: a foot that finds
    the ground level with the other feet is a level step whatever the body's height, so flat ground
    right after another class does not look like a step down or up."""
    level = _swing_step_mm(0.0, 0.0)
    assert abs(_swing_step_mm(0.015, 0.0) - level) < 0.5
    assert abs(_swing_step_mm(-0.01, 0.0) - level) < 0.5
    assert abs(_swing_step_mm(0.0, 0.02) - level - 20.0) < 0.5
