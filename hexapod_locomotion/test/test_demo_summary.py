"""The demo's summary and the experiment's table say why a figure is missing, and print no '-0.00'."""
import os
import subprocess
from types import SimpleNamespace

from hexapod_locomotion.trials.demo import summary_lines
from hexapod_locomotion.trials.experiments import format_table4, summarize_table4


def _res(distance_m):
    return SimpleNamespace(reached_course_end=False, fell=False, distance_m=distance_m, sim_time_s=3.0, phases=2,
                           cot=None, detection=None, temperature_femur_c=[])


def test_a_walk_of_a_hair_backwards_is_zero_metres():
    assert summary_lines(_res(-0.001))[0].startswith('walked 0.00 m in 3.0 s')
    assert summary_lines(_res(0.004))[0].startswith('walked 0.00 m')
    assert summary_lines(_res(-0.02))[0].startswith('walked -0.02 m')


def _trial(gait, t_des, detector, cot):
    return {'config': {'gait': gait, 't_des_s': t_des, 'detector': detector}, 'fell': False, 'detection': None,
            'cot': {'cot': cot, 'speed_mps': 0.05} if cot else None,
            'warnings': [] if cot else ['CoT not computed: the walk lasted 4.6 s from its first swing-down, '
                                        'shorter than one 10 s window']}


def test_the_table_says_why_cot_and_speed_are_missing():
    text = format_table4(summarize_table4([_trial('tripod', 0.5, 'fixed', None), _trial('tripod', 0.5, 'adaptive', None)]))
    note = [ln for ln in text.splitlines() if ln.startswith('CoT and speed -')]
    assert len(note) == 1 and '2 cell(s)' in note[0] and 'walk lasted 4.6 s' in note[0] and '--duration 11' in note[0], text
    text = format_table4(summarize_table4([_trial('tripod', 0.5, 'fixed', 14.0)]))
    assert 'CoT and speed -' not in text


def test_a_demo_too_short_for_the_cot_says_so_before_it_walks(tmp_path):
    from hexapod_testing import installed_executable
    res = subprocess.run([installed_executable('hexapod_locomotion', 'demo'), '--duration', '2', '--terrain', 'flat',
                          '--record', '', '--no-progress'], capture_output=True, text=True, timeout=300, cwd=tmp_path,
                         env=dict(os.environ, HEXAPOD_EXE='demo', HEXAPOD_PROG='./hexapod demo'))
    assert res.returncode == 0, res.stderr
    lines = res.stdout.splitlines()
    first = next(i for i, ln in enumerate(lines) if ln.startswith('note: the cost of transport (Eq. 18) needs 10 s'))
    assert '--duration 11 or more' in lines[first]
    assert first < next(i for i, ln in enumerate(lines) if ln.startswith('walked '))
