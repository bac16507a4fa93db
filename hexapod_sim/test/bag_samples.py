"""Shared by the bag I/O tests: sample messages of the recorded types, a bag written from them, and
decoded messages compared field by field."""
import dataclasses
from pathlib import Path

import numpy as np
import pytest

from hexapod_model import contract
from hexapod_sim.bagio import BagWriter

T0 = 1_700_000_000_000_000_000
JS = 'sensor_msgs/msg/JointState'
REPO = Path(__file__).resolve().parents[2]
NODE_READER = REPO / 'tools' / 'mcap-node' / 'read.mjs'


stamp = contract.stamp_dict_ns


def joint_state(t_ns, names, pos):
    return {'header': {'stamp': stamp(t_ns), 'frame_id': ''}, 'name': list(names), 'position': list(pos)}


def sample_messages():
    """(topic as the bag stores it, type, dict, t_ns) covering nested arrays, fixed arrays,
    constants-bearing types."""
    out = []
    for i in range(40):
        t = T0 + i * 7_000_000
        out.append((contract.JOINT_COMMANDS, JS, joint_state(t, ['leg1_coxa', 'leg1_femur'], [0.1 * i, -0.2 * i]), t))
        out.append((contract.JOINT_STATES, JS, {**joint_state(t + 1000, ['leg1_femur'], [0.1 * i - 0.01]),
                                                 'velocity': [0.5], 'effort': []}, t + 1000))
        if i % 10 == 0:
            out.append((contract.IMU, 'sensor_msgs/msg/Imu', {
                'header': {'stamp': stamp(t), 'frame_id': 'base'},
                'orientation': {'x': 0.0, 'y': 0.0, 'z': 0.0, 'w': 1.0},
                'orientation_covariance': [float(k) for k in range(9)],
                'linear_acceleration': {'x': 0.1, 'y': 0.2, 'z': 9.81}}, t + 2000))
            out.append((contract.SERVO_DIAGNOSTICS, 'hexapod_msgs/msg/ServoDiagnostics', {
                'header': {'stamp': stamp(t), 'frame_id': ''},
                'servos': [{'joint_name': 'leg2_tibia', 'id': 9, 'temperature_c': 41.5, 'voltage_v': 11.9,
                            'load_fraction': -0.25, 'error_bits': 32, 'responding': True,
                            'torque_enabled': False, 'message': 'overload'}]}, t + 3000))
            out.append((contract.SIM_TRUTH_CONTACTS, 'std_msgs/msg/Float64MultiArray', {
                'layout': {'dim': [{'label': 'leg', 'size': 6, 'stride': 6}], 'data_offset': 0},
                'data': [1.0, 0.0, 1.0, 0.0, 1.0, 0.0]}, t + 4000))
    return [(contract.bag_topic(topic), *rest) for topic, *rest in out]


def write_bag(path, msgs, **kw):
    with BagWriter(path, **kw) as w:
        for topic, typ, msg, t in msgs:
            w.write(topic, typ, msg, t)
    return path


def as_plain(obj):
    """Decoded message -> nested dict/list of Python values for comparisons."""
    if dataclasses.is_dataclass(obj):       # rosbags messages
        return {f.name: as_plain(getattr(obj, f.name)) for f in dataclasses.fields(obj)}
    if hasattr(obj, '__slots__') and not isinstance(obj, (str, bytes)):
        return {k: as_plain(getattr(obj, k)) for k in obj.__slots__}
    if isinstance(obj, (list, tuple)):
        return [as_plain(x) for x in obj]
    if isinstance(obj, np.ndarray):
        return [as_plain(x) for x in obj.tolist()]
    if isinstance(obj, (bytes, bytearray)):
        return list(obj)
    if isinstance(obj, np.generic):
        return obj.item()
    return obj


def assert_subset(expected, actual, path='msg'):
    """Every field given in ``expected`` has that value in ``actual`` (absent fields = defaults)."""
    if isinstance(expected, dict):
        for k, v in expected.items():
            assert_subset(v, actual[k], f'{path}.{k}')
    elif isinstance(expected, list):
        assert len(expected) == len(actual), path
        for i, (e, a) in enumerate(zip(expected, actual)):
            assert_subset(e, a, f'{path}[{i}]')
    elif isinstance(expected, float):
        assert actual == pytest.approx(expected, rel=1e-6), path
    else:
        assert expected == actual, path
