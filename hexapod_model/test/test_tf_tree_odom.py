"""TfTree with leg odometry: ``odom -> base_link`` and, with a truth pose, ``world -> odom`` (one parent per frame)."""
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from hexapod_model.description import load_robot
from hexapod_model.tf_tree import TfTree, matrix_of, transform_stamped


def _m(xyz, q):
    return matrix_of(transform_stamped('a', 'b', 0.0, xyz, q)['transform'])


def test_world_to_odom_composes_with_odometry_to_the_truth():
    tree = TfTree(load_robot())
    truth_q = Rotation.from_euler('z', 0.3).as_quat()               # x y z w
    tree.set_body_pose([1.0, 2.0, 0.1], [truth_q[3], *truth_q[:3]])  # w x y z
    odo_q = Rotation.from_euler('z', 0.25).as_quat()
    tree.set_odom_pose('odom', 'base_link', [0.5, 0.1, 0.1], odo_q)
    e = {(p, c): (xyz, q) for p, c, xyz, q in tree.dynamic_entries()}
    assert ('world', 'base_link') not in e
    world_odom = _m(*e[('world', 'odom')])
    odom_base = _m(*e[('odom', 'base_link')])
    assert world_odom @ odom_base == pytest.approx(_m([1.0, 2.0, 0.1], truth_q), abs=1e-12)


def test_odometry_alone_gives_odom_to_base_link():
    tree = TfTree(load_robot())
    tree.set_odom_pose('odom', 'base_link', [0.5, 0.0, 0.1], [0, 0, 0, 1])
    assert [(p, c) for p, c, _, _ in tree.dynamic_entries()] == [('odom', 'base_link')]
    tree.set_odom_pose('odom', 'base_link', [np.nan, 0, 0], [0, 0, 0, 1])     # ignored
    assert tree.odom_pose[2] == (0.5, 0.0, 0.1)
