"""Experiments on every executor: Ray tasks give the process pool's results, and a sweep.

Short walks (2 s of simulated time) on the mockup: the point is the executor and the sweep plumbing,
not the walking, which the locomotion tests cover. Ray runs a local instance with 2 CPUs and no
dashboard (this machine has 2 cores shared with other work).
"""
import dataclasses
import json

import pytest

from hexapod_locomotion.trials import sweep
from hexapod_locomotion.trials.executor import map_jobs
from hexapod_locomotion.trials.experiments import run_many
from hexapod_locomotion.trials.trial_runner import TrialConfig

SHORT = dict(duration_s=2.0, course_end_m=2.6)


def _strip(results):
    return [{k: v for k, v in r.items() if k != 'events'} for r in results]


def test_ray_tasks_give_the_process_pool_results(monkeypatch):
    pytest.importorskip('ray')
    cfgs = [TrialConfig(gait='tripod', detector='adaptive', seed=0, **SHORT),
            TrialConfig(gait='tetrapod', detector='fixed', seed=1, **SHORT)]
    pool = run_many(cfgs, jobs=2, desc='pool')
    from hexapod_locomotion.trials import experiments
    monkeypatch.setitem(experiments.EXECUTOR, 'ray', 'local')
    on_ray = run_many(cfgs, jobs=2, desc='ray')
    assert [r['config'] for r in on_ray] == [r['config'] for r in pool]      # the order of the configs
    assert json.dumps(_strip(on_ray), sort_keys=True) == json.dumps(_strip(pool), sort_keys=True)
    assert pool[0]['phases'] > 0 and pool[1]['config']['gait'] == 'tetrapod'


def test_an_unreachable_ray_cluster_is_one_line(capsys):
    pytest.importorskip('ray')
    from hexapod_locomotion.trials.executor import ExecutorError
    from hexapod_model.cli_common import positive_int
    with pytest.raises(ExecutorError, match='no Ray cluster answers at 127.0.0.1:1'):
        map_jobs(positive_int, ['1'], ray_address='127.0.0.1:1', progress=False)
    with pytest.raises(ExecutorError, match='HOST:PORT'):
        map_jobs(positive_int, ['1'], ray_address='nonsense', progress=False)


def test_sequential_and_pool_keep_the_order():
    args = ['3', '1', '2', '5']
    from hexapod_model.cli_common import positive_int
    assert map_jobs(positive_int, args, jobs=1, progress=False) == [3, 1, 2, 5]
    assert map_jobs(positive_int, args, jobs=2, progress=False) == [3, 1, 2, 5]


def test_two_value_sweep_writes_one_json_and_one_plot(tmp_path, capsys):
    rc = sweep.main(['epsilon_tick', '3', '6', '--duration', '2', '--jobs', '1', '--out', str(tmp_path),
                     '--no-progress'])
    assert rc == 0
    report = json.loads((tmp_path / 'sweep_epsilon_tick.json').read_text())
    assert report['param'] == 'epsilon_tick' and report['values'] == [3.0, 6.0]
    assert [r['config']['epsilon_tick'] for r in report['trials_results']] == [3.0, 6.0]
    assert all(r['config']['gait'] == 'tripod' and r['config']['duration_s'] == 2.0 for r in report['trials_results'])
    assert [s['value'] for s in report['summary']] == [3.0, 6.0]
    assert all(s['trials'] == 1 for s in report['summary'])
    # a larger margin cannot detect ground earlier on the same walk (seed 0, same terrain)
    d3, d6 = (s['delay_ms'] for s in report['summary'])
    assert d3 is not None and d6 is not None and d6 >= d3
    assert (tmp_path / 'sweep_epsilon_tick.png').stat().st_size > 10_000
    out = capsys.readouterr().out
    assert 'sweep of epsilon_tick' in out and 'sweep_epsilon_tick.json' in out


@pytest.mark.parametrize('argv, message', [
    (['epsilonn', '3', '4'], "unknown parameter 'epsilonn'"),
    (['t_des_s', '1', 'fast'], "t_des_s: expected a number, got 'fast'"),
    (['gait', 'tripod', 'hexa'], "gait: must be one of tripod, tetrapod, pentapod, got 'hexa'"),
    (['overlays', 'missing.yaml'], "no such overlay file 'missing.yaml'"),
    (['epsilon_tick', '3', '3'], 'a value is given twice'),
    (['overlap_transfer', 'true', 'maybe'], "overlap_transfer: expected true or false, got 'maybe'"),
    (['t_swing_up_s', '0.1', '0'], 't_swing_up_s: must be a finite number in (0, 10], got 0'),
    (['max_stride_m', '0.07', '-1'], 'max_stride_m: must be a finite number >= 0, got -1'),
    (['approach_rate', '0.5', '2'], 'approach_rate: must be a finite number in (0, 1], got 2'),
    (['confirm_reads', '3'], "unknown parameter 'confirm_reads'"),
    (['terrain', 'mockup', 'moon'], "terrain: must be one of flat, blocks"),
    (['seed', '1'], "unknown parameter 'seed'"),
    (['duration_s', '0'], 'duration_s: must be a finite number > 0, got 0'),
    (['t_settle_s', 'none'], "t_settle_s: expected a number, got 'none'"),
])
def test_bad_sweep_arguments_are_one_line(argv, message, tmp_path, capsys):
    with pytest.raises(SystemExit) as exc:
        sweep.main(argv + ['--out', str(tmp_path / 'o')])
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0] and 'Traceback' not in err[0]
    assert not (tmp_path / 'o').exists()                     # nothing left behind


def test_the_gait_cycle_timing_reaches_the_controller():
    """TrialConfig's transfer-phase fields are the LocomotionParams a trial walks with, and a sweep
    parses a field as its declared type."""
    from hexapod_locomotion.core.locomotion_params import LocomotionParams
    from hexapod_locomotion.trials.trial_runner import locomotion_params
    default = LocomotionParams()
    # the trials' one difference from the node's: the paper's swing, without the obstacle reflex
    assert locomotion_params(TrialConfig()) == dataclasses.replace(default, obstacle_lift_m=0.0)
    p = locomotion_params(TrialConfig(t_swing_up_s=0.15, t_level_s=0.25, max_stride_m=0.07, overlap_transfer=False))
    assert (p.t_swing_up_s, p.t_level_s, p.max_stride_m, p.overlap_transfer) == (0.15, 0.25, 0.07, False)
    assert p.t_swing_forward_s == default.t_swing_forward_s
    assert sweep.parse_value('overlap_transfer', 'false') is False
    assert sweep.parse_value('overlap_transfer', 'True') is True
    assert sweep.parse_value('course_end_m', 'none') is None and sweep.parse_value('course_end_m', '3') == 3.0
    assert sweep.parse_value('t_settle_s', '0.1') == 0.1
    assert sweep.parse_value('overlays', 'a.yaml,b.yaml') == ('a.yaml', 'b.yaml')
    assert sweep.parse_value('gait', 'pentapod') == 'pentapod'


def test_the_discrepancy_bench_walks_are_calibration_walks():
    """The bench records its walks with the installed calibration-walk parameter file, the one a
    robot's walk is recorded with: the cycle of Fig. 4 in sequence, unhurried transfer phases."""
    from hexapod_locomotion.bench.discrepancy_bench import calibration_walk
    from hexapod_locomotion.trials.trial_runner import locomotion_params
    values = calibration_walk()
    assert values['overlap_transfer'] is False and values['t_swing_up_s'] >= 0.15
    p = locomotion_params(TrialConfig(**values))
    assert p.transfer_s() > locomotion_params(TrialConfig()).transfer_s()
