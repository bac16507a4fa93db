"""terrain_node in the ROS graph: with the sim node and the locomotion node (lock-stepped) on slippery
ground it publishes /terrain once per gait cycle; a model file it cannot use stops it with one line."""
import os
import subprocess
import threading
import time

import pytest

rclpy = pytest.importorskip('rclpy')

from hexapod_model.contract import stamp_seconds  # noqa: E402
from hexapod_testing import installed_executable, node_env  # noqa: E402

DOMAIN_ID = 210 + os.getpid() % 20          # 210..229


def test_a_bad_model_file_stops_the_node_with_one_line(tmp_path):
    bad = tmp_path / 'bad.pkl.gz'
    bad.write_bytes(b'not a model')
    r = subprocess.run([installed_executable('hexapod_locomotion', 'terrain_node'), '--ros-args', '-p',
                        f'model:={bad}'], env=node_env(DOMAIN_ID), capture_output=True, text=True, timeout=120)
    assert r.returncode == 2
    assert r.stderr.strip().count('\n') == 0 and 'bad.pkl.gz: not a terrain model file' in r.stderr


@pytest.fixture
def nodes():
    env = node_env(DOMAIN_ID)
    procs = [subprocess.Popen([installed_executable('hexapod_sim', 'sim_node'), '--ros-args', '-p',
                               'terrain:=class_slippery', '-p', 'seed:=12', '-p', 'lockstep:=true'], env=env,
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL),
             subprocess.Popen([installed_executable('hexapod_locomotion', 'locomotion_node'), '--ros-args',
                               '-p', 'lockstep:=true', '-p', 'default_vx:=0.05'], env=env,
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL),
             subprocess.Popen([installed_executable('hexapod_locomotion', 'terrain_node')], env=env,
                              stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)]
    yield procs
    for p in procs:
        if p.poll() is None:
            p.kill()
            p.wait()


def test_terrain_is_published_once_per_gait_cycle(nodes):
    from rclpy.executors import SingleThreadedExecutor

    from hexapod_msgs.msg import SwingDownStart, TerrainClass
    ctx = rclpy.context.Context()
    rclpy.init(context=ctx, domain_id=DOMAIN_ID)
    node = rclpy.create_node('terrain_probe', context=ctx)
    seen = {'terrain': [], 'swing': []}
    node.create_subscription(TerrainClass, '/terrain', lambda m: seen['terrain'].append(m), 10)
    node.create_subscription(SwingDownStart, '/swing_down', lambda m: seen['swing'].append(m), 10)
    ex = SingleThreadedExecutor(context=ctx)
    ex.add_node(node)
    th = threading.Thread(target=ex.spin, daemon=True)
    th.start()
    deadline = time.monotonic() + 480      # a failure bound only: lock-step runs at the speed the machine allows
    try:
        while len(seen['terrain']) < 4 and time.monotonic() < deadline and all(p.poll() is None for p in nodes):
            time.sleep(0.5)
    finally:
        ex.shutdown()
        node.destroy_node()
        rclpy.shutdown(context=ctx)
    assert len(seen['terrain']) >= 3, [p.poll() for p in nodes]
    starts = [stamp_seconds(m.header.stamp) for m in seen['swing']]
    # the probe may join after the first swing-downs (the nodes start first): judge the cycles it saw whole
    judged = [m for m in seen['terrain'] if starts and stamp_seconds(m.cycle_start) >= starts[0]]
    assert judged, (starts, [stamp_seconds(m.cycle_start) for m in seen['terrain']])
    for m in judged:
        # a tripod cycle: two swing-downs, closed at the start of the next one
        assert stamp_seconds(m.header.stamp) in starts and stamp_seconds(m.cycle_start) in starts
        inside = [t for t in starts if stamp_seconds(m.cycle_start) <= t < stamp_seconds(m.header.stamp)]
        assert len(inside) == 2
        assert m.terrain == 'slippery' and 0.5 < m.confidence <= 1.0
        assert sorted(m.classes) == ['blocks', 'flat', 'rough', 'slippery', 'soft']
        assert abs(sum(m.probabilities) - 1.0) < 1e-6
