"""The MuJoCo hexapod as the bus emulator's ``sim`` backend: found through the driver's entry-point
group (the driver never imports the sim), and the real driver core running the sim through it."""
import os
import subprocess
import time
from pathlib import Path

import pytest

from hexapod_driver.bus import DynamixelBus
from hexapod_driver.config import DriverConfig
from hexapod_driver.emulator import BACKEND_GROUP, BusEmulator, backend_plugins
from hexapod_model.description import ALL_JOINTS, load_robot
from hexapod_sim.node.emulator_backend import SimBackend

ROOT = Path(__file__).resolve().parents[2]
# Generous reply timeout: the CI machine is shared and loaded; a lost reply then costs ~30 ms.
BASE = dict(timeout_margin_ms=25.0, read_retries=1, missing_after_failures=2, reprobe_period_s=0.05,
            reconnect_period_s=0.05, diagnostics_period_s=0.2, command_timeout_s=0.0)


@pytest.fixture(scope='module')
def robot():
    return load_robot()


def test_the_sim_backend_is_registered_in_the_emulator_plugin_group():
    plugins = backend_plugins()
    assert BACKEND_GROUP == 'hexapod_driver.emulator_backends'
    assert 'sim' in plugins
    assert plugins['sim'].load() is SimBackend


def test_bus_emulator_help_lists_the_sim_backend_and_its_options():
    script = ROOT / 'install' / 'hexapod_driver' / 'lib' / 'hexapod_driver' / 'bus_emulator'
    res = subprocess.run([str(script), '--help'], capture_output=True, text=True, timeout=120, env=dict(os.environ))
    assert res.returncode == 0, res.stderr
    text = ' '.join(res.stdout.split())
    assert 'sim: the MuJoCo hexapod' in text and '--terrain' in text and '--fixed-base' in text


def test_driver_runs_the_mujoco_sim_through_the_emulator(robot):
    args = type('Args', (), {'terrain': 'flat', 'terrain_seed': 0, 'fixed_base': True, 'max_catch_up_ms': 2.0,
                             'truth_out': None})()
    backend = SimBackend.create(robot, args)          # what `bus_emulator --backend sim --fixed-base` builds
    sim = backend.bus
    with BusEmulator(robot, backend) as emu:
        b = DynamixelBus(robot, DriverConfig(device=emu.port, **BASE))
        b.start()
        try:
            assert b.set_command(['leg1_femur'], [0.4]) == []
            b.set_schedule(['leg1_femur'])
            goal = b.to_tick('leg1_femur', 0.4)
            settled = sim.now() + 1.0                                   # 1 s of simulated time to settle
            diag, last = None, None
            t_end = time.monotonic() + 10.0
            while time.monotonic() < t_end and (diag is None or last is None):
                r = b.step()
                if sim.now() > settled:
                    last = r.samples[-1] if r.samples else last
                    diag = r.diagnostics or diag
            assert sim.goal_ticks()[ALL_JOINTS.index('leg1_femur')] == goal
            # the femur holds the leg against gravity a few ticks short of its goal (firmware P law)
            assert 0 <= goal - last.tick <= 4
            femur = {d.joint: d for d in diag}['leg1_femur']
            assert femur.load_fraction == pytest.approx((goal - femur.present_tick) / robot.servo.compliance_slope_ticks,
                                                        abs=0.05)
            assert femur.temperature_c == pytest.approx(float(sim.temperatures_c()[1]), abs=1.0)
        finally:
            b.close()
        assert not sim.torque_enabled.any()


def test_reads_through_the_emulator_leave_the_physics_on_the_emulator_clock(robot):
    """However often the driver reads, the physics keeps to the emulator's clock: a read over the
    pseudo-terminal costs its own round trip, not the millisecond an in-process read adds. (Each
    read used to push the physics 1 ms on; a driver reading a little faster than 1 kHz had it run
    up to 0.6 s ahead of the wall clock, its settle pauses cut short.)"""
    args = type('Args', (), {'terrain': 'flat', 'terrain_seed': 0, 'fixed_base': True, 'max_catch_up_ms': 2.0,
                             'truth_out': None})()
    backend = SimBackend.create(robot, args)
    sim = backend.bus
    t = 0.010
    backend.idle(t)
    ticks = [backend.sample(t, slot)[0] for slot in range(18) for _ in range(3)]      # 54 reads at one instant
    assert sim.now() - backend.t0 == pytest.approx(t, abs=sim.dt)
    assert len(ticks) == 54
    backend.idle(t + 0.001)
    assert sim.now() - backend.t0 == pytest.approx(t + 0.001, abs=sim.dt)


def test_an_unwritable_truth_file_is_refused_before_the_physics_is_built(tmp_path):
    """--truth-out is written at exit: a folder that cannot take it, or another extension, is one line at start."""
    import sys
    for out in (tmp_path / 'missing' / 'truth.npz', tmp_path / 'truth.csv'):
        r = subprocess.run([sys.executable, '-m', 'hexapod_driver.emulator', '--backend', 'sim', '--truth-out', str(out)],
                           capture_output=True, text=True, timeout=60, stdin=subprocess.DEVNULL)
        err = r.stderr.strip().splitlines()
        assert r.returncode == 2 and r.stdout == '' and 'Traceback' not in r.stderr, r.stderr
        assert len(err) == 1 and err[0].startswith('bus_emulator: error: argument --truth-out: '), r.stderr
    assert list(tmp_path.iterdir()) == []
