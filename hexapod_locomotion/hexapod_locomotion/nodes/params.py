"""locomotion_node's parameters (:mod:`hexapod_model.param_schema`). No ROS import.

Gait, detector and the swing-down timing are read-only: the controller is built and warmed up once
at start (the swing-down models are compiled for the gait's legs and t_des), and a change in the
middle of a gait cycle would split a swing-down between two models. Restart the node to change
them. ``cmd_vel_timeout_s`` is read at every use and may change at run time.
"""
from __future__ import annotations

import re
from dataclasses import dataclass

from hexapod_locomotion.core.controller import MAX_STEP_S, LocomotionParams
from hexapod_locomotion.core.detector import DETECTOR_KINDS, DetectorConfig
from hexapod_locomotion.core.gait import load_gaits
from hexapod_model.param_schema import NodeSpec, RobotSource, param

_GAIT = LocomotionParams()


def _frame_id(value) -> str | None:
    """A TF frame id: letters, digits, '_' and '/' (REP 105 names: odom, base_link), not empty."""
    if not re.fullmatch(r'[A-Za-z_][A-Za-z0-9_/]*', value):
        return 'must be a TF frame id: a letter or _ first, then letters, digits, _ or / (e.g. odom, base_link)'
    return None
_DET = DetectorConfig()


@dataclass(frozen=True)
class LocomotionNodeParams:
    gait: str = param('tripod', 'gait (gaits.yaml)', choices=tuple(load_gaits()))
    detector: str = param(_DET.kind, "ground detection: 'adaptive' (model threshold, Eq. 17) or 'fixed' (constant "
                          'baseline threshold)', choices=DETECTOR_KINDS)
    epsilon_tick: float = param(_DET.epsilon_tick, 'Eq. 17 margin [ticks]; too small stops legs early, too large '
                                'stops late', min=0.0)
    dwell_epsilon_tick: float = param(_DET.dwell_epsilon_tick, 'Eq. 17 margin [ticks] while a leg dwells at theta_fin '
                                      '(fin_dwell_s > 0): the goal stands still there, so a smaller margin finds a '
                                      'contact at the end of a slow approach; too small and a free leg at theta_fin is '
                                      'taken for a contact (leveled on ground that is not there); the default is Eq. '
                                      '17\'s 3 ticks, the experiments\' improved touchdown uses 1', min=0.0)
    fixed_threshold_tick: float = param(_DET.fixed_threshold_tick, 'baseline threshold [ticks] of the fixed '
                                        'detector', min=0.0)
    t_des_s: float = param(_GAIT.t_des_s, 'swing-down duration [s]; shorter is faster but hits the ground harder',
                           min=0.0, min_exclusive=True, max=MAX_STEP_S)
    t_com_s: float = param(0.0, 'duration of one bus read [s]; 0 = from the robot description', min=0.0)
    lift_m: float = param(_GAIT.lift_m, 'swing-up height [m]', min=0.0)
    ground_depth_m: float = param(_GAIT.ground_depth_m, 'theta_fin this far below the nominal ground [m]; deeper '
                                  '= faster swing-down', min=0.0)
    landing_preload: float = param(_GAIT.landing_preload, 'a leg that found ground is leveled as carrying this '
                                   'fraction of its share of the weight (compensates servo compliance; 0 = off, '
                                   'for rigid servos)', min=0.0)
    approach_rate: float = param(_GAIT.approach_rate, 'touchdown goal profile: 1 = the paper\'s Eq. 15 (constant goal '
                                 'rate); below 1 = the improved touchdown, the goal slows to this fraction of the Eq. 15 '
                                 'rate from approach_height_m above the expected ground (less push on the body at '
                                 'contact; a longer swing-down); too small makes walking slow', min=0.0, max=1.0,
                                 min_exclusive=True)
    approach_height_m: float = param(_GAIT.approach_height_m, 'with approach_rate < 1: the slow approach starts this '
                                     'high above the expected ground [m]; too small and contacts meet the fast goal, too '
                                     'large and the swing-down is slow all the way', min=0.0)
    fin_dwell_s: float = param(_GAIT.fin_dwell_s, 'keep reading a leg whose goal reached theta_fin this long [s] '
                               'before giving up on ground (0 = Algorithm 1); too long delays the next phase when '
                               'there is no ground', min=0.0, max=MAX_STEP_S)
    t_swing_up_s: float = param(_GAIT.t_swing_up_s, 'swing-up duration [s]; shorter is faster but jerks the body',
                                min=0.0, min_exclusive=True, max=MAX_STEP_S)
    t_swing_forward_s: float = param(_GAIT.t_swing_forward_s, 'swing-forward duration [s]; shorter is faster but the '
                                     'leg may not settle before the swing-down', min=0.0, min_exclusive=True, max=MAX_STEP_S)
    t_settle_s: float = param(_GAIT.t_settle_s, 'pause before the swing-down [s]; too short and a model started at '
                              'rest (start_in_motion false) mispredicts the start', min=0.0, max=MAX_STEP_S)
    t_level_s: float = param(_GAIT.t_level_s, 'body leveling and forward motion duration [s]; shorter is faster but '
                             'loads the servos harder', min=0.0, min_exclusive=True, max=MAX_STEP_S)
    overlap_transfer: bool = param(_GAIT.overlap_transfer, 'gait-cycle structure: true = the body leveling after a '
                                   'swing-down runs while the next group swings up and forward (the phase takes '
                                   'max(t_level_s, t_swing_up_s + t_swing_forward_s) besides settle and swing-down); '
                                   'false = every step in sequence, as drawn in the paper\'s Fig. 4 (slower)')
    start_in_motion: bool = param(_GAIT.start_in_motion, 'start Algorithm 1\'s model in the leg\'s motion at the '
                                  'swing-down start (the leg model run over the transfer\'s goals); false = at rest, as '
                                  'before (needs a settle long enough for the legs to stop)')
    start_ramp: bool = param(_GAIT.start_ramp, 'grow the stride over the first gait cycle (from the home stance a '
                             'full stride spreads the feet further than any later cycle); false = full stride at once')
    max_stride_m: float = param(_GAIT.max_stride_m, 'largest foothold displacement per cycle [m]; 0 = the gait\'s '
                                'own (gaits.yaml: tripod 0.09, tetrapod 0.10, pentapod 0.12); beyond reach is clamped',
                                min=0.0)
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
    heading_correction: bool = param(True, 'follow /cmd_vel with the odometry (and /imu when it is published): '
                                     'correct the heading towards the commanded yaw rate and the sideways drift off the '
                                     'commanded line; false = the paper\'s open loop (the command as it is)')
    lockstep: bool = param(False, 'drive a lock-stepped bus master (sim_node lockstep:=true): advance it by '
                           'publishing commands instead of waiting for wall time (the time is the reads\' stamps: '
                           'use_sim_time is not needed and only adds a /clock subscription)')


@dataclass(frozen=True)
class ComposedParams:
    """The composed ``robot`` executable's own choice, read before its nodes are made."""

    hardware: str = param('sim', 'bus master composed with the controller: sim (the MuJoCo hexapod) or driver '
                          '(the AX-12A bus on the driver\'s device: the robot, or the bus emulator)',
                          choices=('sim', 'driver'))


NODE = NodeSpec('hexapod_locomotion', 'locomotion_node', 'locomotion_node', (RobotSource, LocomotionNodeParams))
