"""bench_driver: the benchmark runs end to end against the emulator process, and its split of a read
into transport and servo time adds up (figures are not judged here: benchmarks print, tests do not time)."""
import subprocess
import sys

import numpy as np

from hexapod_driver.bench_driver import split_round_trips


def test_split_recovers_the_parts_of_each_read():
    rng = np.random.default_rng(0)
    stamps = np.cumsum(rng.uniform(2e-4, 5e-4, 200)) + 1.7e9
    up, servo, down = 30e-6, 160e-6, 40e-6
    arrival = stamps + up
    emulator = np.column_stack([arrival, arrival + servo])
    # an answered instruction the driver did not time (a write) sits between two reads
    extra = np.column_stack([stamps[:-1] + 0.9 * np.diff(stamps)] * 2)
    emulator = np.vstack([emulator, extra])
    emulator = emulator[np.argsort(emulator[:, 0])]
    sp = split_round_trips(stamps, np.full(200, up + servo + down), emulator)
    assert sp['matched'] == 200
    assert np.allclose([sp['up'], sp['servo'], sp['down']], [up, servo, down], atol=1e-7)   # wall-clock stamps: ~0.1 us resolution


def test_a_read_without_an_emulator_entry_is_not_matched_to_a_later_one():
    stamps = np.array([0.0, 1.0])
    emulator = np.array([[1.0 + 3e-5, 1.0 + 1.9e-4]])   # only the second read reached the emulator
    sp = split_round_trips(stamps, np.array([2.3e-4, 2.3e-4]), emulator)
    assert sp['matched'] == 1


def test_bench_driver_runs_against_the_emulator_process(tmp_path):
    r = subprocess.run([sys.executable, '-m', 'hexapod_driver.bench_driver', '--reads', '200', '--modes', 'wire'],
                       capture_output=True, text=True, timeout=120, cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert 'median split of' in r.stdout and 'pseudo-terminal round trip' in r.stdout
    assert list(tmp_path.iterdir()) == []                      # the emulator's timing file is removed


def test_the_emulator_runs_as_a_module_and_refuses_a_bad_timing_file():
    r = subprocess.run([sys.executable, '-m', 'hexapod_driver.emulator', '--timing-out', 'times.csv'],
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 2
    assert 'must name a .npy file' in r.stderr and 'Traceback' not in r.stderr
