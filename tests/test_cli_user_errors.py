"""Every command, run as its console script with bad input, fails at once
with ONE line on stderr (no traceback), a non-zero exit status, and leaves nothing behind; its
usage line names the ./hexapod command when started through ./hexapod."""
import os
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
INSTALL = ROOT / 'install'

CASES = [   # (package, executable, arguments)
    ('hexapod_locomotion', 'demo', ['--gait', 'bogus']),
    ('hexapod_locomotion', 'demo', ['--t-des', 'nan']),
    ('hexapod_locomotion', 'demo', ['--t-des', '-1']),
    ('hexapod_locomotion', 'demo', ['--t-des', '1e9']),      # refused up front, not a memory error mid-run
    ('hexapod_locomotion', 'demo', ['--video', 'walk.gif', '--duration', '1e6']),   # the GIF's frames: the same
    ('hexapod_sim', 'sim', ['--video', 'x.gif', '--duration', '1e9']),
    ('hexapod_sim', 'discrepancy', ['BAG', '--json', '/proc/no_folder/x.json']),   # a folder that cannot be made
    ('hexapod_locomotion', 'demo', ['--duration', '-5']),
    ('hexapod_locomotion', 'demo', ['--video', 'walk.mp4']),
    ('hexapod_locomotion', 'demo', ['--terrain', 'lava']),
    ('hexapod_locomotion', 'demo', ['--overlay', 'OVERLAY']),
    ('hexapod_sim', 'sim', ['--render', 'x.jpg']),
    ('hexapod_sim', 'sim', ['--video', 'x.gif', '--duration', '-1']),
    ('hexapod_sim', 'sim', ['--render', 'x.png', '--overlay', 'OVERLAY']),
    ('hexapod_sim', 'sim', ['--urdf', 'x.urdf', '--overlay', 'OVERLAY']),
    ('hexapod_sim', 'sim', ['--urdf', 'x.xml']),
    ('hexapod_sim', 'sim', ['--foxglove', '70000']),
    ('hexapod_locomotion', 'demo', ['--foxglove', 'x']),
    ('hexapod_sim', 'tf_figure', ['x.jpg']),
    ('hexapod_sim', 'sim', ['--mjcf', 'no_such_dir/x.xml']),
    ('hexapod_sim', 'sim', ['--mjcf', 'x.urdf']),
    ('hexapod_sim', 'sim', ['--mjcf', 'x.xml', '--overlay', 'OVERLAY']),
    ('hexapod_locomotion', 'experiment', ['table4', '--trials', '0']),
    ('hexapod_locomotion', 'experiment', ['quality', '--duration', 'inf']),
    ('hexapod_locomotion', 'experiment', ['table4', '--approach-rate', '1']),
    ('hexapod_locomotion', 'analyse', ['nonexistent_bag']),
    ('hexapod_locomotion', 'analyse', ['BAG', '--plot', 'p.xyz']),
    ('hexapod_sim', 'discrepancy', ['nonexistent_bag']),
    ('hexapod_sim', 'discrepancy', ['BAG', '--overlay', 'OVERLAY']),
    ('hexapod_sim', 'discrepancy', ['BAG', '--min-ratio', '0.5']),
    ('hexapod_sim', 'discrepancy', ['BAG', '--search-budget', '0']),
    ('hexapod_sim', 'discrepancy', ['BAG', '--search-budget', 'nan']),
    ('hexapod_locomotion', 'discrepancy_bench', ['--seed', 'x']),
    ('hexapod_locomotion', 'discrepancy_bench', ['--reuse']),
    ('hexapod_sim', 'replay', ['nonexistent_bag']),
    ('hexapod_driver', 'servo_tool', ['scan', '--device', '/dev/nonexistent_tty']),
    ('hexapod_driver', 'servo_tool', ['set-id', '--to', '-3']),
    # description, overlay and bag errors name the file the user edits or gave, once
    ('hexapod_locomotion', 'demo', ['--overlay', 'NEG_OVERLAY']),
    ('hexapod_locomotion', 'demo', ['--overlay', 'BAD_YAML']),
    ('hexapod_sim', 'sim', ['--overlay', 'NEG_OVERLAY']),
    ('hexapod_sim', 'sim', ['--record', 'BAG']),
    ('hexapod_locomotion', 'demo', ['--record', '/proc/no_bag_here']),   # looks writable to root, is not
    ('hexapod_sim', 'discrepancy', ['EMPTY_DIR']),
    ('hexapod_sim', 'discrepancy', ['BAG', '--overlay', 'NEG_OVERLAY']),
    ('hexapod_locomotion', 'analyse', ['EMPTY_DIR']),
    ('hexapod_locomotion', 'analyse', ['BAD_YAML']),
    ('hexapod_sim', 'replay', ['EMPTY_DIR']),
    ('hexapod_sim', 'replay', ['BAG', '--rate', 'nan']),
    ('hexapod_model', 'bench_model', ['--repeats', '-1']),
    ('hexapod_model', 'bench_model', ['--t-des', '0.0001']),
    ('hexapod_sim', 'record_contract', ['--out', 'BAG']),
    ('hexapod_sim', 'record_contract', ['--out', '/proc/no_bag_here']),        # root passes os.access there
    ('hexapod_sim', 'discrepancy', ['BAG', '--json', '/proc/no_report.json']),  # refused before the analysis
    ('hexapod_locomotion', 'analyse', ['BAG', '--json', '/proc/no_report.json']),
    ('hexapod_sim', 'stand_calibration', ['--out', '/proc/no_bag_here']),
    ('hexapod_sim', 'stand_calibration', ['--out', 'new_bag', '--device', '/dev/nonexistent_tty']),
    ('hexapod_locomotion', 'experiment', ['table4', '--out', '/proc/no_folder_here']),
    ('hexapod_locomotion', 'experiment', ['sweep', 'epsilon_tick', '3', '--out', '/proc/no_folder_here']),
    ('hexapod_locomotion', 'discrepancy_bench', ['--keep', '/proc/no_folder_here']),
    ('hexapod_locomotion', 'experiment', ['table4', '--out', 'BAD_YAML']),              # a file, not a folder
    ('hexapod_sim', 'record_contract', ['--out', 'new_bag', '--duration', 'nan']),
    ('hexapod_sim', 'stand_calibration', ['--out', 'new_bag', '--speed-scale', '-1']),
    ('hexapod_locomotion', 'experiment', ['sweep', 't_des_s', 'nan']),
    ('hexapod_locomotion', 'discrepancy_bench', ['--jobs', '0']),
    ('hexapod_locomotion', 'discrepancy_bench', ['--seed', '-1']),
    ('hexapod_locomotion', 'discrepancy_bench', ['--legs', '9']),
    ('hexapod_locomotion', 'discrepancy_bench', ['--json', 'no_such_dir/x.json']),   # not after the whole run
    ('hexapod_locomotion', 'random_bench', ['--cases', '0']),
    ('hexapod_locomotion', 'random_bench', ['--only', '5', '--cases', '3']),
    ('hexapod_locomotion', 'random_bench', ['--json', 'no_such_dir/x.json']),
    ('hexapod_sim', 'replay', ['BAG', '--delay', 'nan']),
    ('hexapod_locomotion', 'cmd_vel_pub', ['--vx', 'nan']),
    ('hexapod_locomotion', 'cmd_vel_pub', ['--duration', '-1']),
    ('hexapod_locomotion', 'teleop_keyboard', ['--rate', 'nan']),
    ('hexapod_locomotion', 'soak', ['--minutes', 'nan']),
    ('hexapod_locomotion', 'soak', ['--minutes', '1', '--out', 'BAD_YAML']),          # exists: nothing overwritten
    ('hexapod_locomotion', 'robot', ['--gait', 'bogus']),      # a node: parameters are -p NAME:=VALUE
    ('hexapod_driver', 'driver_node', ['--device', '/dev/ttyUSB0']),
    # ROS arguments rcl cannot parse: the node's one line, not rcl's traceback
    ('hexapod_locomotion', 'robot', ['--ros-args', '-p', '-p']),
    ('hexapod_locomotion', 'locomotion_node', ['--ros-args', '-p', 'gait']),
    ('hexapod_model', 'model_node', ['--ros-args', '-r']),
    ('hexapod_sim', 'sim_node', ['--ros-args', '-p', '-p']),
    ('hexapod_driver', 'driver_node', ['--ros-args', '-p', '-p']),
    ('hexapod_locomotion', 'terrain_node', ['--ros-args', '-p', '-p']),
    ('hexapod_locomotion', 'terrain_node', ['--model', 'm.pkl.gz']),    # a node: parameters are -p NAME:=VALUE
    ('hexapod_sim', 'replay', ['BAG', '--ros-args', '-p', '-p']),
    # a bag the terrain classifier cannot read: the bag reader's one line, under the subcommand's name
    ('hexapod_locomotion', 'terrain', ['evaluate', 'nonexistent_bag']),
    ('hexapod_locomotion', 'terrain', ['evaluate', 'BAD_YAML']),
    ('hexapod_locomotion', 'terrain', ['train', 'EMPTY_DIR']),
    ('hexapod_locomotion', 'terrain', ['train', '--set', 'train', '--out', '/proc/no_folder/m.pkl.gz']),  # not after the walks
    ('hexapod_locomotion', 'terrain', ['record', 'BAG', '--terrain', 'class_flat']),    # exists: nothing overwritten
]
# --help lists ROS parameters: 'name (default X): ...'
ROS_NODES = {'robot', 'driver_node', 'locomotion_node', 'model_node', 'sim_node', 'terrain_node'}
NO_DEFAULTS = {'analyse',               # every option is an output asked for (--json, --plot) or a switch
               'terrain'}               # only subcommands at the top; their options show their defaults


@pytest.mark.parametrize('pkg, exe, args', CASES, ids=[f'{c[1]} {" ".join(c[2])}' for c in CASES])
def test_bad_input_is_one_line_and_leaves_nothing(tmp_path, pkg, exe, args):
    raw = args
    script = INSTALL / pkg / 'lib' / pkg / exe
    assert script.exists(), script
    files = {'OVERLAY': tmp_path / 'typo_overlay.yaml', 'NEG_OVERLAY': tmp_path / 'negative_mass.yaml',
             'BAD_YAML': tmp_path / 'broken.yaml', 'EMPTY_DIR': tmp_path / 'empty_dir',
             'BAG': ROOT / 'bags' / 'tripod_blocks_fixed'}
    files['OVERLAY'].write_text('efects: []\n')
    files['NEG_OVERLAY'].write_text('total_mass_kg: -1\n')
    files['BAD_YAML'].write_text('servo: [unclosed\n')
    files['EMPTY_DIR'].mkdir()
    args = [str(files[a]) if a in files else a for a in args]
    run_dir = tmp_path / 'cwd'
    run_dir.mkdir()
    bags = tmp_path / 'bags'
    bags.mkdir()
    env = dict(os.environ, HEXAPOD_BAGS=str(bags), HEXAPOD_EXE=exe, HEXAPOD_PROG=f'./hexapod {exe}')
    res = subprocess.run([str(script), *args], cwd=run_dir, env=env, capture_output=True, text=True, timeout=120)
    err = res.stderr.strip().splitlines()
    assert res.returncode != 0, res.stdout
    assert len(err) == 1, res.stderr
    assert 'Traceback' not in res.stderr and 'warnings.warn' not in res.stderr
    assert err[0].startswith(f'./hexapod {exe}') and ': error: ' in err[0], err[0]
    assert list(run_dir.iterdir()) == [] and list(bags.iterdir()) == []      # nothing created
    assert list((tmp_path / 'empty_dir').iterdir()) == []
    # a file is named as the user gave it or by its source (never the copy under build/ or install/), once
    assert '/build/' not in err[0] and '/install/' not in err[0], err[0]
    for a in args:
        if a.startswith(str(tmp_path)) or a.startswith(str(ROOT)):
            assert err[0].count(a) <= 1, err[0]
    if 'NEG_OVERLAY' in raw:
        assert f'merged over {ROOT}/hexapod_model/hexapod_model/data/robot.yaml' in err[0], err[0]


@pytest.mark.parametrize('pkg, exe', sorted({(c[0], c[1]) for c in CASES}))
def test_help_names_the_hexapod_command_and_shows_defaults(pkg, exe):
    script = INSTALL / pkg / 'lib' / pkg / exe
    env = dict(os.environ, HEXAPOD_EXE=exe, HEXAPOD_PROG=f'./hexapod {exe}')
    res = subprocess.run([str(script), '--help'], env=env, capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stderr
    assert res.stdout.startswith(f'usage: ./hexapod {exe} ')
    text = ' '.join(res.stdout.split())
    assert '(default: True)' not in text and '(default: False)' not in text      # switches show none
    if exe not in NO_DEFAULTS:
        assert ('(default ' if exe in ROS_NODES else '(default: ') in text
    first = next(line for line in res.stdout.split('\n\n')[1].splitlines() if line.strip())
    assert res.stdout.count(first.strip()) == 1          # the description is printed once


def test_an_unknown_hexapod_command_is_one_line_naming_the_nearest():
    """A mistyped subcommand is one line naming it and the nearest known one, not the whole usage."""
    res = subprocess.run([str(ROOT / 'hexapod'), 'dmeo'], capture_output=True, text=True, timeout=120,
                         stdin=subprocess.DEVNULL)
    assert res.returncode != 0 and res.stdout == ''
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1, res.stderr
    assert "unknown command 'dmeo'" in lines[0] and "did you mean 'demo'?" in lines[0], lines[0]
