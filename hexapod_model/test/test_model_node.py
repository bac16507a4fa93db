"""model_node serves the same predictions as the library, and names bad requests."""
import os
import threading

import numpy as np
import pytest

rclpy = pytest.importorskip('rclpy')

from hexapod_model.contract import PREDICT_SWING_DOWN  # noqa: E402
from hexapod_model.description import load_robot  # noqa: E402
from hexapod_model.swing_model import predict_swing_down  # noqa: E402


@pytest.fixture(scope='module')
def client():
    from rclpy.executors import MultiThreadedExecutor

    from hexapod_model.model_node import ModelNode
    from hexapod_msgs.srv import PredictSwingDown
    os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    ctx = rclpy.context.Context()
    rclpy.init(context=ctx)     # ROS_DOMAIN_ID: the test run's own (./hexapod test sets it)
    server = ModelNode(context=ctx)
    caller = rclpy.create_node('model_node_test_client', context=ctx)
    cli = caller.create_client(PredictSwingDown, PREDICT_SWING_DOWN)
    ex = MultiThreadedExecutor(context=ctx)
    ex.add_node(server)
    ex.add_node(caller)
    th = threading.Thread(target=ex.spin, daemon=True)
    th.start()
    assert cli.wait_for_service(timeout_sec=10.0)

    def call(**fields):
        req = PredictSwingDown.Request()
        for k, v in fields.items():
            setattr(req, k, v)
        return cli.call(req, timeout_sec=10.0)

    yield call
    ex.shutdown()
    server.destroy_node()
    caller.destroy_node()
    rclpy.shutdown(context=ctx)


def test_service_matches_library(client):
    robot = load_robot()
    resp = client(legs=[1, 6, 3], femur_init_rad=[0.45] * 3, tibia_init_rad=[0.1] * 3, femur_fin_rad=[-0.15] * 3,
                  tibia_fin_rad=[-0.05] * 3, t_des_s=1.0, t_com_s=0.001, epsilon_tick=3.0, max_steps=100)
    assert resp.success, resp.message
    lib = predict_swing_down(robot, [1, 6, 3], [[0.45, 0.1]] * 3, [[-0.15, -0.05]] * 3, 1.0, 0.001, n_steps=100)
    assert np.asarray(resp.threshold_tick) == pytest.approx(lib.threshold_tick.ravel())
    assert np.asarray(resp.t_read_s) == pytest.approx(lib.t_read_s.ravel())
    assert len(resp.theta_est_tick) == 300


def test_bad_request_is_named(client):
    resp = client(legs=[1, 9], femur_init_rad=[0.4], tibia_init_rad=[0.1], femur_fin_rad=[0.0], tibia_fin_rad=[0.0],
                  t_des_s=1.0, t_com_s=0.001, epsilon_tick=3.0)
    assert not resp.success and 'legs must be 1..6' in resp.message
    resp = client(legs=[2], femur_init_rad=[0.4], tibia_init_rad=[0.1], femur_fin_rad=[0.0], tibia_fin_rad=[0.0],
                  t_des_s=-1.0, t_com_s=0.001, epsilon_tick=3.0)
    assert not resp.success and 't_des_s' in resp.message


def test_a_start_in_motion_is_served_like_the_library(client):
    robot = load_robot()
    common = dict(legs=[1, 6], femur_init_rad=[0.45] * 2, tibia_init_rad=[0.1] * 2, femur_fin_rad=[-0.15] * 2,
                  tibia_fin_rad=[-0.05] * 2, t_des_s=0.5, t_com_s=0.001, epsilon_tick=3.0, max_steps=60)
    resp = client(femur_init_rad_s=[-1.5, 0.5], tibia_init_rad_s=[0.8, 0.0], **common)
    assert resp.success, resp.message
    lib = predict_swing_down(robot, [1, 6], [[0.45, 0.1]] * 2, [[-0.15, -0.05]] * 2, 0.5, 0.001, n_steps=60,
                             qd0_rad_s=[[-1.5, 0.8], [0.5, 0.0]])
    assert np.asarray(resp.theta_est_tick) == pytest.approx(lib.theta_est_tick.ravel())
    at_rest = client(**common)
    assert np.asarray(at_rest.theta_est_tick) != pytest.approx(lib.theta_est_tick.ravel())
    resp = client(femur_init_rad_s=[-1.5], tibia_init_rad_s=[0.8], **common)
    assert not resp.success and 'one entry per leg' in resp.message
    resp = client(femur_init_rad_s=[float('nan'), 0.0], tibia_init_rad_s=[0.0, 0.0], **common)
    assert not resp.success and 'speeds' in resp.message


def test_the_running_model_node_refuses_bad_start_speeds_and_serves_on():
    """The installed model_node process: a request with a NaN start speed gets one named refusal, the
    node keeps serving (a request with start speeds is answered), and Ctrl-C ends it cleanly."""
    import subprocess

    from hexapod_msgs.srv import PredictSwingDown
    from hexapod_testing import installed_executable, node_env, ros_probe, stop_process
    domain = 220 + os.getpid() % 13                  # 220..232 (Fast DDS refuses above 232): this test's own
    proc = subprocess.Popen([installed_executable('hexapod_model', 'model_node')], env=node_env(domain),
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        with ros_probe('model_node_process_test', domain) as (node, ex):
            cli = node.create_client(PredictSwingDown, PREDICT_SWING_DOWN)
            assert cli.wait_for_service(timeout_sec=30.0), 'model_node did not come up'

            def call(**fields):
                req = PredictSwingDown.Request(legs=[1, 6], femur_init_rad=[0.45] * 2, tibia_init_rad=[0.1] * 2,
                                               femur_fin_rad=[-0.15] * 2, tibia_fin_rad=[-0.05] * 2, t_des_s=0.5,
                                               t_com_s=0.001, epsilon_tick=3.0, max_steps=20, **fields)
                fut = cli.call_async(req)
                ex.spin_until_future_complete(fut, timeout_sec=30.0)
                assert fut.done(), 'no answer from model_node'
                return fut.result()
            bad = call(femur_init_rad_s=[float('nan'), 0.0], tibia_init_rad_s=[0.0, 0.0])
            assert not bad.success and 'speeds' in bad.message
            good = call(femur_init_rad_s=[-1.5, 0.5], tibia_init_rad_s=[0.8, 0.0])
            assert good.success and len(good.theta_est_tick) == 40
    finally:
        rc, out = stop_process(proc)
    assert rc == 0, out
    assert 'Traceback' not in out, out
