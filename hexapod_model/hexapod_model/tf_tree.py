"""TF of the robot from joint positions and the body pose, as plain message dicts. No rclpy.

The transforms are the URDF's joints (:func:`hexapod_model.urdf.urdf_joints`), so TF, the URDF and
the DH kinematics agree by construction (and a test checks all three with Pinocchio):

* ``/tf_static``: the fixed joints (``base_link -> trunk``, ``leg{l}_tibia -> leg{l}_foot``);
* ``/tf``: ``world -> base_link`` (the body pose, where one is known: the sim's truth), or with
  leg odometry ``odom -> base_link`` (and ``world -> odom`` so that the truth still places the body), and
  ``parent -> leg{l}_{role}`` for every joint whose position is known.

Messages are dicts in the layout of ``tf2_msgs/msg/TFMessage`` (``transforms`` of
``geometry_msgs/msg/TransformStamped``), for the bag writer; the nodes build their ROS messages
from the same :class:`TfTree`.
"""
from __future__ import annotations

import math
from collections.abc import Iterable, Mapping

import numpy as np
from scipy.spatial.transform import Rotation

from hexapod_model.contract import stamp_parts
from hexapod_model.description import Robot
from hexapod_model.urdf import ROOT_LINK, WORLD_FRAME, urdf_joints


def quat_xyzw(rot: np.ndarray) -> tuple[float, float, float, float]:
    """Unit quaternion (x, y, z, w) of a rotation matrix, w >= 0."""
    q = Rotation.from_matrix(rot).as_quat()
    if q[3] < 0:
        q = -q
    return tuple(float(v) for v in q)


def transform_stamped(parent: str, child: str, t_s: float, translation, quat_xyzw_) -> dict:
    sec, nsec = stamp_parts(t_s)
    x, y, z = (float(v) for v in translation)
    qx, qy, qz, qw = (float(v) for v in quat_xyzw_)
    return {'header': {'stamp': {'sec': sec, 'nanosec': nsec}, 'frame_id': parent}, 'child_frame_id': child,
            'transform': {'translation': {'x': x, 'y': y, 'z': z},
                          'rotation': {'x': qx, 'y': qy, 'z': qz, 'w': qw}}}


def matrix_of(transform: Mapping) -> np.ndarray:
    """4x4 matrix of a ``geometry_msgs/Transform`` given as a dict or a message (attributes)."""
    get = (lambda o, k: o[k]) if isinstance(transform, Mapping) else getattr
    tr, rot = get(transform, 'translation'), get(transform, 'rotation')
    m = np.eye(4)
    m[:3, :3] = Rotation.from_quat([get(rot, k) for k in 'xyzw']).as_matrix()
    m[:3, 3] = [get(tr, k) for k in 'xyz']
    return m


class TfTree:
    """The latest joint positions and body pose of the robot, and the TF messages of them."""

    def __init__(self, robot: Robot):
        self.robot = robot
        self.joints = urdf_joints(robot)
        self._revolute = {j.name: j for j in self.joints if j.kind == 'revolute'}
        # origin @ Rz(theta): the translation is the origin's, the rotation q_origin * q_z(theta)
        self._origin = {n: (tuple(float(v) for v in j.origin[:3, 3]), quat_xyzw(j.origin[:3, :3]))
                        for n, j in self._revolute.items()}
        self.positions: dict[str, float] = {}
        self.body_pose: tuple[tuple, tuple] | None = None    # (xyz, quat xyzw) in world
        # (parent, child, xyz, quat xyzw): the odometry's pose of the body (``odom -> base_link``)
        self.odom_pose: tuple[str, str, tuple, tuple] | None = None

    def set_positions(self, names: Iterable[str], positions: Iterable[float]) -> None:
        """Take the positions of the named joints (names foreign to the robot and NaN are ignored)."""
        for name, pos in zip(names, positions):
            if name in self._revolute and math.isfinite(pos):
                self.positions[name] = float(pos)

    def set_body_pose(self, xyz, quat_wxyz) -> None:
        """World pose of the body frame (``base_link``); quaternion in (w, x, y, z) as MuJoCo's."""
        w, x, y, z = (float(v) for v in quat_wxyz)
        n = math.sqrt(w * w + x * x + y * y + z * z)
        xyz = np.asarray(xyz, dtype=float)
        if not (n > 0 and math.isfinite(n) and np.all(np.isfinite(xyz))):
            return
        self.body_pose = (tuple(float(v) for v in xyz), (x / n, y / n, z / n, w / n))

    def set_odom_pose(self, parent: str, child: str, xyz, quat_xyzw_) -> None:
        """The odometry's pose of ``child`` (the body) in ``parent`` (``odom``). With a world pose of the body
        too, the world's link is then ``world -> odom`` (so ``base_link`` keeps one parent, REP 105)."""
        xyz, q = np.asarray(xyz, dtype=float), np.asarray(quat_xyzw_, dtype=float)
        n = float(np.linalg.norm(q))
        if n > 0 and np.all(np.isfinite(xyz)) and np.all(np.isfinite(q)) and parent and child:
            self.odom_pose = (parent, child, tuple(float(v) for v in xyz), tuple(float(v) for v in q / n))

    def static_entries(self) -> list[tuple[str, str, tuple, tuple]]:
        """(parent, child, translation xyz, rotation xyzw) of the fixed joints."""
        return [(j.parent, j.child, tuple(float(v) for v in j.origin[:3, 3]), quat_xyzw(j.origin[:3, :3]))
                for j in self.joints if j.kind == 'fixed']

    def dynamic_entries(self) -> list[tuple[str, str, tuple, tuple]]:
        """(parent, child, translation xyz, rotation xyzw): the body pose if known, then every joint
        whose position is known."""
        out = []
        if self.odom_pose is not None:
            parent, child, xyz, q = self.odom_pose
            if self.body_pose is not None:
                # world -> odom = (world -> base_link) * (odom -> base_link)^-1
                rw, ro = Rotation.from_quat(self.body_pose[1]), Rotation.from_quat(q)
                r = rw * ro.inv()
                out.append((WORLD_FRAME, parent, tuple(float(v) for v in np.asarray(self.body_pose[0]) - r.apply(xyz)),
                            quat_xyzw(r.as_matrix())))
            out.append((parent, child, xyz, q))
        elif self.body_pose is not None:
            out.append((WORLD_FRAME, ROOT_LINK, tuple(self.body_pose[0]), tuple(self.body_pose[1])))
        for name, j in self._revolute.items():
            if name in self.positions:
                xyz, (x, y, z, w) = self._origin[name]
                half = 0.5 * self.positions[name]
                c, s = math.cos(half), math.sin(half)
                q = (x * c + y * s, y * c - x * s, z * c + w * s, w * c - z * s)   # q_origin * (0, 0, s, c)
                out.append((j.parent, j.child, xyz, q))
        return out

    def static_message(self, t_s: float) -> dict:
        return {'transforms': [transform_stamped(p, c, t_s, xyz, q) for p, c, xyz, q in self.static_entries()]}

    def dynamic_message(self, t_s: float) -> dict:
        return {'transforms': [transform_stamped(p, c, t_s, xyz, q) for p, c, xyz, q in self.dynamic_entries()]}
