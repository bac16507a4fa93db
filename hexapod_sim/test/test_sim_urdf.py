"""``./hexapod sim --urdf OUT``: the URDF of the description (and overlays), or one clear line."""
import os
import subprocess
import sys

import pytest

from hexapod_model.description import load_robot
from hexapod_model.urdf import urdf_xml


@pytest.fixture(scope='module')
def robot():
    return load_robot()


def _sim_cli(*args, cwd):
    env = dict(os.environ)
    return subprocess.run([sys.executable, '-m', 'hexapod_sim.node.cli', *args], cwd=cwd, env=env,
                          capture_output=True, text=True, timeout=120)


@pytest.mark.parametrize('overlay, key', [
    ('links: {femur: {mass_kg: -0.08}}\n', 'links.femur.mass_kg'),
    ('dh: {tibia: {a_m: .nan}}\n', 'dh.tibia.a_m'),
])
def test_cli_urdf_refuses_bad_description_before_writing(tmp_path, overlay, key):
    ov = tmp_path / 'bad.yaml'
    ov.write_text(overlay)
    out = tmp_path / 'out' / 'robot.urdf'
    out.parent.mkdir()
    r = _sim_cli('--urdf', str(out), '--overlay', str(ov), cwd=tmp_path)
    assert r.returncode == 2, r.stderr
    assert 'Traceback' not in r.stderr and key in r.stderr and len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert list(out.parent.iterdir()) == []


def test_cli_urdf_writes_the_description(tmp_path, robot):
    out = tmp_path / 'hexapod.urdf'
    r = _sim_cli('--urdf', str(out), cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert out.read_text() == urdf_xml(robot) and str(out) in r.stdout


@pytest.mark.parametrize('value,why', [('-0.5', 'must be a finite number >= 0, got -0.5'),
                                       ('inf', 'must be a finite number >= 0, got inf')])
def test_cli_rtf_is_refused_by_sim_node_declaration_in_one_line(tmp_path, value, why):
    """``./hexapod sim --rtf`` sets sim_node's real_time_factor: refused for the declaration's reason, before
    a node starts."""
    r = _sim_cli('--rtf', value, cwd=tmp_path)
    assert r.returncode == 2 and 'Traceback' not in r.stderr, r.stderr
    assert len(r.stderr.strip().splitlines()) == 1 and f'argument --rtf: {why}' in r.stderr, r.stderr
