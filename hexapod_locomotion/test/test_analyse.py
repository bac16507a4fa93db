"""Offline re-evaluation of recorded walks (./hexapod analyse)."""
import pytest

from hexapod_locomotion.trials.analyse import main, rerun_detectors
from hexapod_locomotion.trials.trial_runner import TrialConfig, run_trial
from hexapod_sim.bagio import BagError, BagReader, BagWriter


@pytest.fixture(scope='module')
def walk_bag(tmp_path_factory):
    bag = tmp_path_factory.mktemp('bags') / 'walk'
    res = run_trial(TrialConfig(gait='tetrapod', detector='adaptive', t_des_s=0.5, terrain='blocks', duration_s=12,
                                record=str(bag)))
    assert res.phases >= 3
    return bag, res


def test_offline_analysis_reproduces_online_decisions(walk_bag):
    bag, res = walk_bag
    r = rerun_detectors(str(bag))
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


def test_plot_of_a_fixed_detector_bag_marks_what_the_fixed_detector_did(tmp_path):
    """On the fixed-detector reference bag most legs run to theta_fin without a detection and one
    crosses the 21-tick threshold: both are marked as the recorded detector's stops."""
    from pathlib import Path

    from hexapod_locomotion.trials.analyse import plot
    bag = Path(__file__).resolve().parents[2] / 'bags' / 'tripod_blocks_fixed'
    labels = plot(rerun_detectors(str(bag)), tmp_path / 'fixed.png')
    assert 'fixed: ran to theta_fin (recorded)' in labels
    assert 'fixed stop (threshold crossed) (recorded)' in labels
    assert 'adaptive stop (threshold crossed)' in labels and 'fixed threshold' in labels


def test_bag_without_swing_downs_is_refused(tmp_path, capsys):
    with BagWriter(tmp_path / 'js') as w:
        w.write('/joint_states', 'sensor_msgs/msg/JointState', {'name': ['leg1_femur'], 'position': [0.1]}, 1000)
    with pytest.raises(BagError, match='no /swing_down topic'):     # one line, from the one bag loader
        rerun_detectors(str(tmp_path / 'js'))
    assert main([str(tmp_path / 'js'), '--no-progress']) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and 'no /swing_down topic - ' in err[0], err


def test_garbage_gives_clear_error(tmp_path, capsys):
    p = tmp_path / 'junk.mcap'
    p.write_bytes(b'this is not an mcap file at all' * 10)
    with pytest.raises(BagError):
        rerun_detectors(str(p))
    assert main([str(p)]) == 2
    assert 'analyse:' in capsys.readouterr().err


def test_truncated_bag_reports_the_cut_off_swing_down_as_incomplete(walk_bag, tmp_path, capsys):
    """A bag cut in the middle of a swing-down; the cut-off legs are 'incomplete',
    not 'differing decisions'; no 'see JSON' without --json; the bag warning is one clean line."""
    bag, _ = walk_bag
    mcap = next(bag.glob('*.mcap'))
    data = mcap.read_bytes()
    full = rerun_detectors(str(bag))
    # Steps of a quarter of a swing-down's share of the file: steps of 0.1 (about one gait cycle of this
    # 12 s walk) can all land between swing-downs.
    for frac in [0.5 + 0.025 * k for k in range(16)]:
        cut = tmp_path / f'cut{frac}.mcap'
        cut.write_bytes(data[:int(len(data) * frac)])
        r = rerun_detectors(str(cut))
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
    """The demo's summary and analyse's report of one bag: 'swing-down phases' and 'leg swing-downs'
    with the same numbers, and the same speed, power and CoT line (one function, the same samples,
    windows from the first swing-down on)."""
    from hexapod_locomotion.trials.analyse import report_lines
    from hexapod_locomotion.trials.demo import summary_lines
    bag, res = walk_bag
    demo = summary_lines(res)
    r = rerun_detectors(str(bag))
    report = [line.strip() for line in report_lines(r)]
    phases = f'{res.phases} swing-down phases'
    legs = f'{res.detection["swing_downs"]} leg swing-downs'
    assert phases in '\n'.join(demo) and phases in '\n'.join(report)
    assert legs in '\n'.join(demo) and legs in '\n'.join(report)
    cot = next(line for line in demo if 'cost of transport' in line)
    assert cot in report, (cot, report)
    for k in ('cot', 'speed_mps', 'power_w', 'windows'):
        assert r['cot'][k] == pytest.approx(res.cot[k], rel=1e-6), k     # float32 in the bag's /power


def test_a_swing_down_finished_before_the_time_limit_is_counted_by_both(tmp_path):
    """The time limit falls after the last swing-down's decisions but before its gait phase ends
    (body leveling): the demo counts that swing-down, as analyse does from the bag."""
    cfg = dict(gait='tripod', detector='adaptive', t_des_s=0.5, terrain='flat')
    probe = run_trial(TrialConfig(**cfg, duration_s=1.5))
    first = [e for e in probe.events if e['t_swing_start_s'] == probe.events[0]['t_swing_start_s']]
    limit = max(e['t_stop_s'] for e in first) + 0.05       # 50 ms into the 0.3 s of body leveling
    bag = tmp_path / 'cut'
    res = run_trial(TrialConfig(**cfg, duration_s=limit - probe.walk_start_s, record=str(bag)))
    assert any(w.startswith('time limit') for w in res.warnings), res.warnings
    r = rerun_detectors(str(bag))
    assert r['incomplete_swing_downs'] == []
    assert res.phases == r['swing_downs'] == 1 and res.detection['swing_downs'] == r['legs_evaluated'] == 3


def test_demo_and_analyse_commands_print_the_same_figures_for_one_bag(tmp_path, capsys):
    """./hexapod demo, then ./hexapod analyse on its bag: the same swing-down counts and the same
    speed / power / CoT line; the demo's progress bar is on stderr (``demo > log`` holds the
    results only) and its time limit is kept within one control period."""
    import json

    from hexapod_locomotion.trials.demo import main as demo_main
    bag, out = tmp_path / 'walk', tmp_path / 'walk.json'
    assert demo_main(['--terrain', 'flat', '--duration', '12', '--record', str(bag), '--json', str(out)]) == 0
    demo_out, demo_err = capsys.readouterr()
    assert 'walking:' in demo_err and 'walking:' not in demo_out
    res = json.loads(out.read_text())
    t_con = max(e['t_con_s'] for e in res['events'])
    assert 12.0 <= res['sim_time_s'] <= 12.0 + t_con + 1e-9
    assert main([str(bag), '--no-progress']) == 0
    report = capsys.readouterr().out
    assert f'{res["phases"]} swing-down phases, {res["detection"]["swing_downs"]} leg swing-downs' in report
    assert f'{res["phases"]} swing-down phases' in demo_out
    assert f'ground detection: {res["detection"]["swing_downs"]} leg swing-downs' in demo_out
    cot = next(line for line in demo_out.splitlines() if 'cost of transport' in line)
    assert f'  {cot}\n' in report, (cot, report)


def test_demo_says_when_it_writes_the_gif(tmp_path, capsys):
    """The GIF is written after the walk (a pause of seconds): stderr says so after the progress bar,
    stdout names the file."""
    from hexapod_locomotion.trials.demo import main as demo_main
    gif = tmp_path / 'walk.gif'
    assert demo_main(['--terrain', 'flat', '--duration', '1', '--record', '', '--video', str(gif)]) == 0
    out, err = capsys.readouterr()
    assert gif.stat().st_size > 10_000 and f'video: {gif}' in out
    tail = err.replace('\r', '\n').rstrip().splitlines()
    assert tail[-1].startswith(f'writing GIF {gif} (') and 'walking:' in err     # the bar is not redrawn after it


def test_the_improved_touchdown_is_replayed_with_its_dwell_margin(tmp_path):
    """/swing_down carries the dwell's Eq. 17 margin, so analyse re-runs the improved touchdown as the
    walk ran it; a recording made before the field existed replays the dwell with Eq. 17's margin."""
    from hexapod_locomotion.core.detector import DetectorConfig, SwingDownPhase, phase_from_fields, swing_start_fields
    from hexapod_locomotion.trials.experiments import variant_fields
    from hexapod_model.description import load_robot
    bag = tmp_path / 'improved'
    fields = variant_fields('improved')
    assert fields['dwell_epsilon_tick'] < 3.0
    res = run_trial(TrialConfig(gait='tripod', t_des_s=0.5, terrain='blocks', duration_s=12, record=str(bag), **fields))
    r = rerun_detectors(str(bag))
    assert r['swing_downs'] == res.phases >= 3
    assert r['reproduced'] == r['legs_evaluated'] == 3 * res.phases, r['not_reproduced'][:3]
    # read back by an independent reader (rosbags, with the bag's own message definitions)
    from rosbags.rosbag2 import Reader
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore
    store = get_typestore(Stores.EMPTY)
    with Reader(bag) as reader:
        for conn in reader.connections:
            store.register(get_types_from_msg(conn.msgdef.data, conn.msgtype))
        starts = [store.deserialize_cdr(d, c.msgtype) for c, _, d in reader.messages()
                  if c.msgtype == 'hexapod_msgs/msg/SwingDownStart']
    assert len(starts) >= res.phases
    assert {(m.dwell_epsilon_tick, m.epsilon_tick, m.fin_dwell_steps > 0) for m in starts} == {(1.0, 3.0, True)}
    robot = load_robot()
    ph = SwingDownPhase(robot, (1,), [0.0], [[0.9, -0.9]], [[0.05, -0.75]], 0.5, 0.001,
                        DetectorConfig(dwell_epsilon_tick=1.0), fin_dwell_steps=5)
    f = swing_start_fields(ph)
    assert phase_from_fields(robot, f, 0.0).config.dwell_epsilon_tick == 1.0
    old = {k: v for k, v in f.items() if k != 'dwell_epsilon_tick'}
    assert phase_from_fields(robot, old, 0.0).config.dwell_epsilon_tick == old['epsilon_tick'] == 3.0


def test_a_bag_whose_reads_break_algorithm1_order_is_said_so(walk_bag, tmp_path, capsys):
    """Without /ground_detection analyse can only replay the bus's /joint_states in bus order; with a
    read missing there (the first swing-down's first femur read) the reads of that swing-down are out of
    Algorithm 1's order: the report says how many swing-downs cannot be replayed, instead of counting
    their decisions as differing without a word."""
    from hexapod_model.contract import stamp_seconds
    bag, _ = walk_bag
    src = BagReader(str(bag))
    swings = [m for m in src.messages(topics=['/swing_down'])]
    t0, first_leg = stamp_seconds(swings[0][3].header.stamp), int(swings[0][3].legs[0])
    out = tmp_path / 'no_gd'
    dropped = False
    with BagWriter(out) as w:
        for topic, msg_type, t_ns, raw in src.messages(raw=True):
            if topic == '/ground_detection':
                continue
            if topic == '/joint_states' and not dropped:
                msg = next(iter(src.messages(topics=['/joint_states'], start_ns=t_ns, end_ns=t_ns + 1)))[3]
                if list(msg.name) == [f'leg{first_leg}_femur'] and stamp_seconds(msg.header.stamp) >= t0:
                    dropped = True
                    continue
            w.write(topic, msg_type, raw, t_ns)
    assert dropped
    r = rerun_detectors(str(out))
    assert 0 in r['out_of_order_swing_downs']
    assert main([str(out), '--no-progress']) == 0
    said = [line for line in capsys.readouterr().out.splitlines() if 'cannot be replayed' in line]
    assert said == [f'  {len(r["out_of_order_swing_downs"])} of {r["swing_downs"]} swing-down phases cannot be replayed: '
                    'the recorded reads are out of Algorithm 1 order and the bag does not say which reads the '
                    'controller took (no complete /ground_detection); their decisions are not reproduced']
