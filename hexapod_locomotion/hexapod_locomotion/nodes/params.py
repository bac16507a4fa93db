"""locomotion_node's parameters (:mod:`hexapod_model.param_schema`). No ROS import.

Gait, detector and the swing-down timing are read-only: the controller is built and warmed up once
at start (the swing-down models are compiled for the gait's legs and t_des), and a change in the
middle of a gait cycle would split a swing-down between two models. Restart the node to change
them. ``cmd_vel_timeout_s`` is read at every use and may change at run time.
"""
from __future__ import annotations

import re
from dataclasses import dataclass

from hexapod_locomotion.core.course import CourseChoice
from hexapod_locomotion.core.detector import DetectorConfig
from hexapod_locomotion.core.gait import GaitChoice
from hexapod_locomotion.core.locomotion_params import LocomotionParams
from hexapod_model.param_schema import NodeSpec, ReadTime, RobotSource, param


def _frame_id(value) -> str | None:
    """A TF frame id: letters, digits, '_' and '/' (REP 105 names: odom, base_link), not empty."""
    if not re.fullmatch(r'[A-Za-z_][A-Za-z0-9_/]*', value):
        return 'must be a TF frame id: a letter or _ first, then letters, digits, _ or / (e.g. odom, base_link)'
    return None


@dataclass(frozen=True)
class LocomotionNodeParams:
    """What only the node has; the gait, the controller's, the detector's, the read time's and the course
    correction's parameters are declared by :class:`GaitChoice`, :class:`LocomotionParams`,
    :class:`DetectorConfig`, :class:`ReadTime` and :class:`CourseChoice` (see :data:`NODE`)."""


    cmd_vel_timeout_s: float = param(
        2.0, 'stop walking (finish the phase, then stand) when the last /cmd_vel is older than this [s of bus '
        'time]; longer than the period of common publishers (ros2 topic pub: 1 s), so one late message does not '
        'stop the robot; may change at run time', min=0.0, min_exclusive=True, read_only=False)
    default_vx: float = param(0.0, 'forward speed [m/s] used when no /cmd_vel has been received')
    read_timeout_s: float = param(0.0, 'give up on a position read after this wall time [s]; 0 = 2 s, or 10 s in '
                                  'lockstep (over DDS a loaded machine delivers reads late; a lock-stepped sim '
                                  'answers late but surely)', min=0.0)
    odom_frame: str = param('odom', 'frame of the leg odometry (REP 105): /odom\'s header.frame_id and the parent '
                            'of the odometry transform on /tf', rule=_frame_id)
    base_frame: str = param('base_link', 'the body frame (REP 105): /odom\'s child_frame_id and the child of the '
                            'odometry transform; must be the robot description\'s root link for a connected TF tree',
                            rule=_frame_id)
    lockstep: bool = param(False, 'drive a lock-stepped bus master (sim_node lockstep:=true): advance it by '
                           'publishing commands instead of waiting for wall time (the time is the reads\' stamps: '
                           'use_sim_time is not needed and only adds a /clock subscription)')


@dataclass(frozen=True)
class ComposedParams:
    """The composed ``robot`` executable's own choice, read before its nodes are made."""

    hardware: str = param('sim', 'bus master composed with the controller: sim (the MuJoCo hexapod) or driver '
                          '(the AX-12A bus on the driver\'s device: the robot, or the bus emulator)',
                          choices=('sim', 'driver'))


NODE = NodeSpec('hexapod_locomotion', 'locomotion_node', 'locomotion_node',
                (RobotSource, GaitChoice, LocomotionParams, DetectorConfig, ReadTime, CourseChoice, LocomotionNodeParams))


@dataclass(frozen=True)
class TerrainNodeParams:
    """terrain_node's own parameter (the robot description's are :class:`RobotSource`'s)."""

    model: str = param('', 'terrain model file (./hexapod terrain train writes one); empty = the packaged '
                       'hexapod_locomotion/data/terrain_model.pkl.gz')


TERRAIN_NODE = NodeSpec('hexapod_locomotion', 'terrain_node', 'terrain_node', (RobotSource, TerrainNodeParams))
