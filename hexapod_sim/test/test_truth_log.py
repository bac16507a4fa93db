"""The per-millisecond truth a benchmark takes from the sim (hexapod_sim.physics.truth_log), the cheap
foot-contact test behind it, and the sim node writing it as a running process."""
import os
import signal
import subprocess
import time

import numpy as np
import pytest

import hexapod_testing as testing
from hexapod_model.description import ALL_JOINTS, load_robot
from hexapod_sim.physics.plant import HexapodSim, SimError
from hexapod_sim.physics.truth_log import TRUTH_COLUMNS, TruthLog, load_truth

DOMAIN_ID = 150 + os.getpid() % 40


def _paw(sim, i):
    """Femurs swinging up and down together: feet leave and touch the ground again and again."""
    if i % 20 == 0:
        ph = np.sin(i * 0.004)
        sim.sync_write({j: (0.4 * ph if j.endswith('femur') else 0.0) for j in ALL_JOINTS})
    sim.wait_until(sim.now() + 0.001)


def test_feet_touching_last_step_is_foot_contacts_one_step_earlier_and_leaves_the_run_alone():
    robot = load_robot()
    a, b = HexapodSim(robot, terrain='blocks'), HexapodSim(robot, terrain='blocks')
    before = a.foot_contacts().in_contact
    changes = 0
    for i in range(3000):
        _paw(a, i)
        _paw(b, i)
        last, now = a.feet_touching_last_step(), a.foot_contacts().in_contact
        assert np.array_equal(last, before), f'at {a.now():.3f} s'
        changes += not np.array_equal(last, now)
        before = now
    assert changes > 20                      # steps in which a foot landed or lifted were checked
    assert np.array_equal(a.data.qpos, b.data.qpos)     # b never asked: same physics to the bit


def test_truth_log_keeps_one_row_per_millisecond_and_round_trips(tmp_path):
    sim = HexapodSim(load_robot(), terrain='flat')
    log = TruthLog(str(tmp_path / 'truth.npz'))
    for i in range(200):
        _paw(sim, i)
        log.sample(sim)
        log.sample(sim)                      # a second call within the same millisecond adds nothing
    log.save()
    truth = load_truth(str(tmp_path / 'truth.npz'))
    assert truth.shape == (200, len(TRUTH_COLUMNS))
    assert np.allclose(np.diff(truth[:, 1]), 0.001)
    assert np.all(np.diff(truth[:, 0]) >= 0)                  # wall clock
    assert set(np.unique(truth[:, 5:11])) <= {0.0, 1.0}
    assert os.listdir(tmp_path) == ['truth.npz']              # no partial file left


@pytest.mark.parametrize('path, what', [('nodir/truth.npz', 'does not exist'), ('truth.csv', 'must end in .npz')])
def test_truth_log_refuses_a_path_it_cannot_write(tmp_path, path, what):
    with pytest.raises(SimError, match=what):
        TruthLog(str(tmp_path / path))


def test_load_truth_names_a_file_that_is_not_a_truth_file(tmp_path):
    np.savez(tmp_path / 'other.npz', truth=np.zeros((3, 4)))
    (tmp_path / 'junk.npz').write_bytes(b'not a zip')
    with pytest.raises(SimError, match='expected N x 11'):
        load_truth(str(tmp_path / 'other.npz'))
    with pytest.raises(SimError, match='cannot be read'):
        load_truth(str(tmp_path / 'junk.npz'))


@pytest.mark.parametrize('sig', [signal.SIGINT, signal.SIGTERM])
def test_the_sim_node_process_writes_its_truth_when_it_stops(tmp_path, sig):
    out = tmp_path / 'truth.npz'
    proc = subprocess.Popen([testing.installed_executable('hexapod_sim', 'sim_node'), '--ros-args',
                             '-p', 'real_time_factor:=0.0', '-p', f'truth_out:={out}'],
                            env=testing.node_env(DOMAIN_ID), stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            text=True)
    lines = []
    for line in proc.stdout:               # runs as fast as it can once ready
        lines.append(line)
        if 'sim ready' in line:
            break
    time.sleep(1.0)
    rc, rest = testing.stop_process(proc, sig)
    log = ''.join(lines) + rest
    assert rc == 0 and 'Traceback' not in log, log
    truth = load_truth(str(out))
    assert len(truth) > 50
    assert np.allclose(np.diff(truth[:, 1]), 0.001, atol=1e-9)     # a row per millisecond of physics
    assert truth[-20:, 5:11].all()                 # settled from the drop at start: six feet down


def test_the_sim_node_refuses_a_truth_file_in_a_missing_directory(tmp_path):
    r = subprocess.run([testing.installed_executable('hexapod_sim', 'sim_node'), '--ros-args',
                        '-p', f'truth_out:={tmp_path}/missing/truth.npz'],
                       env=testing.node_env(DOMAIN_ID), capture_output=True, text=True, timeout=60)
    assert r.returncode != 0
    assert 'does not exist' in r.stderr + r.stdout and 'Traceback' not in r.stderr + r.stdout
