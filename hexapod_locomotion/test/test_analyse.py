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


def test_truncated_bag_reports_the_cut_off_swing_down_as_incomplete(walk_bag, tmp_path, capsys):
    """Issue 14 item 6: a bag cut in the middle of a swing-down; the cut-off legs are 'incomplete',
    not 'differing decisions'; no 'see JSON' without --json; the bag warning is one clean line."""
    bag, _ = walk_bag
    mcap = next(bag.glob('*.mcap'))
    data = mcap.read_bytes()
    full = analyse(str(bag))
    # chunk boundaries follow wall time too (crash-safe flushing): try cuts at many places
    for frac in (0.5, 0.55, 0.6, 0.65, 0.7, 0.75, 0.8, 0.85, 0.9):
        cut = tmp_path / f'cut{frac}.mcap'
        cut.write_bytes(data[:int(len(data) * frac)])
        r = analyse(str(cut))
        if r['incomplete_swing_downs']:
            break
    else:
        pytest.fail('no truncation cut a swing-down')
    assert r['not_reproduced'] == [] and r['reproduced'] == r['legs_evaluated']
    assert r['swing_downs'] < full['swing_downs'] and r['bag_warnings']
    assert main([str(cut), '--no-progress']) == 0
    out, err = capsys.readouterr()
    assert 'incomplete' in out and 'differ' not in out and 'JSON' not in out
    assert err.count('\n') == len(r['bag_warnings']) and err.startswith('analyse: warning: ')
    assert 'warnings.warn' not in err and 'BagWarning' not in err


def test_demo_and_analyse_use_the_same_words_and_counts(walk_bag):
    """Issue 14 item 13: 'swing-down phases' and 'leg swing-downs' with the same numbers."""
    from hexapod_locomotion.analyse import report_lines
    from hexapod_locomotion.demo import summary_lines
    bag, res = walk_bag
    demo_text = '\n'.join(summary_lines(res))
    text = '\n'.join(report_lines(analyse(str(bag))))
    phases = f'{res.phases} swing-down phases'
    legs = f'{res.detection["swing_downs"]} leg swing-downs'
    assert phases in demo_text and phases in text
    assert legs in demo_text and legs in text
