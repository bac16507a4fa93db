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
    ('hexapod_locomotion', 'discrepancy_bench', ['--seed', 'x']),
    ('hexapod_sim', 'replay', ['nonexistent_bag']),
    ('hexapod_driver', 'servo_tool', ['scan', '--device', '/dev/nonexistent_tty']),
    ('hexapod_driver', 'servo_tool', ['set-id', '--to', '-3']),
]


@pytest.mark.parametrize('pkg, exe, args', CASES, ids=[f'{c[1]} {" ".join(c[2])}' for c in CASES])
def test_bad_input_is_one_line_and_leaves_nothing(tmp_path, pkg, exe, args):
    script = INSTALL / pkg / 'lib' / pkg / exe
    assert script.exists(), script
    overlay = tmp_path / 'typo_overlay.yaml'
    overlay.write_text('efects: []\n')
    bag = ROOT / 'bags' / 'tripod_blocks_fixed'
    args = [str(overlay) if a == 'OVERLAY' else str(bag) if a == 'BAG' else a for a in args]
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


@pytest.mark.parametrize('pkg, exe', sorted({(c[0], c[1]) for c in CASES}))
def test_help_names_the_hexapod_command_and_shows_defaults(pkg, exe):
    script = INSTALL / pkg / 'lib' / pkg / exe
    env = dict(os.environ, HEXAPOD_EXE=exe, HEXAPOD_PROG=f'./hexapod {exe}')
    res = subprocess.run([str(script), '--help'], env=env, capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stderr
    assert res.stdout.startswith(f'usage: ./hexapod {exe} ')
    assert '(default: ' in ' '.join(res.stdout.split())
    first = next(line for line in res.stdout.split('\n\n')[1].splitlines() if line.strip())
    assert res.stdout.count(first.strip()) == 1          # the description is printed once
