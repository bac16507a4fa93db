"""Offline re-evaluation of recorded walks (./hexapod analyse)."""
import pytest

from hexapod_locomotion.analyse import AnalysisError, analyse, main
from hexapod_locomotion.sim_run import TrialConfig, run_trial
from hexapod_model.bagio import BagError, BagWriter


@pytest.fixture(scope='module')
def walk_bag(tmp_path_factory):
    bag = tmp_path_factory.mktemp('bags') / 'walk'
    res = run_trial(TrialConfig(gait='tetrapod', detector='adaptive', t_des_s=0.5, terrain='blocks', duration_s=12,
                                record=str(bag)))
    assert res.phases >= 3
    return bag, res


def test_offline_analysis_reproduces_online_decisions(walk_bag):
    bag, res = walk_bag
    r = analyse(str(bag))
    assert r['swing_downs'] == res.phases
    assert r['legs_evaluated'] == 2 * res.phases
    assert r['reproduced'] == r['legs_evaluated'], r['not_reproduced'][:3]
    assert r['problems'] == []
    online = {(round(e['t_swing_start_s'], 6), e['leg']): e['t_stop_s'] - e['t_swing_start_s'] for e in res.events}
    for v in r['verdicts']:
        assert v['replay_same_stop_s'] == pytest.approx(online[(round(v['t_start_s'], 6), v['leg'])], abs=1e-9)
    assert r['cot'] is not None and r['stability'] is not None


def test_cli_json_and_plot(walk_bag, tmp_path, capsys):
    bag, _ = walk_bag
    assert main([str(bag), '--json', str(tmp_path / 'a.json'), '--plot', str(tmp_path / 'a.png')]) == 0
    assert (tmp_path / 'a.png').stat().st_size > 10_000
    assert 'reproduces' in capsys.readouterr().out


def test_bag_without_swing_downs_is_refused(tmp_path):
    with BagWriter(tmp_path / 'js') as w:
        w.write('/joint_states', 'sensor_msgs/msg/JointState', {'name': ['leg1_femur'], 'position': [0.1]}, 1000)
    with pytest.raises(AnalysisError, match='/swing_down'):
        analyse(str(tmp_path / 'js'))


def test_garbage_gives_clear_error(tmp_path, capsys):
    p = tmp_path / 'junk.mcap'
    p.write_bytes(b'this is not an mcap file at all' * 10)
    with pytest.raises(BagError):
        analyse(str(p))
    assert main([str(p)]) == 2
    assert 'analyse:' in capsys.readouterr().err
