"""What one trial walks: :class:`TrialConfig`, derived from the settings' declarations. No rclpy.

A trial's own settings (duration, command, outputs) are declared in :class:`TrialSettings`; the
scene's are sim_node's (:class:`~hexapod_sim.physics.scene_params.SceneParams`), the read time is
the bus masters' (:class:`~hexapod_model.param_schema.ReadTime`), the course correction
(:class:`~hexapod_locomotion.core.course.CourseChoice`), the gait, the controller's and the
detector's are locomotion_node's (:class:`~hexapod_locomotion.core.gait.GaitChoice`,
:class:`~hexapod_locomotion.core.locomotion_params.LocomotionParams`,
:class:`~hexapod_locomotion.core.detector.DetectorConfig`), with the same names, types, defaults
(but :data:`TRIAL_DEFAULTS`) and ranges. :class:`TrialConfig` is the union of these groups' parameter fields
(:func:`hexapod_model.param_schema.merged_schema`): nothing is restated, and
:func:`locomotion_params` / :func:`detector_config` read a group back by its field names.
"""
from __future__ import annotations

from dataclasses import dataclass

from hexapod_locomotion.core.course import CourseChoice
from hexapod_locomotion.core.detector import DetectorConfig
from hexapod_locomotion.core.gait import GaitChoice
from hexapod_locomotion.core.locomotion_params import LocomotionParams
from hexapod_model.cli_common import param_float
from hexapod_model.param_schema import ReadTime, merged_schema, param, specs, values
from hexapod_sim.physics.scene_params import SceneParams


def _positive(default, description: str):
    return param(default, description, min=0.0, min_exclusive=True)


@dataclass(frozen=True)
class TrialSettings:
    """A trial's own settings: the walk's command, limits and outputs."""

    duration_s: float = _positive(60.0, 'simulated walking time limit [s]')
    course_end_m: float | None = param(None, 'stop once the trunk passes this x [m]; none = no course end')
    vx_mps: float = param(0.05, 'commanded forward speed [m/s]')
    wz_rad_s: float = param(0.0, 'commanded yaw rate [rad/s]')
    probe_period_s: float = _positive(0.05, 'truth sampling period (pose, energy, temperature) [s]')
    record: str | None = param(None, 'bag directory to record to; none = no recording')
    overlays: tuple[str, ...] = param((), 'robot-description overlay YAMLs, in order')
    video: str | None = param(None, 'animated GIF of the walk (offscreen CPU rendering); none = no video')
    video_fps: float = _positive(10.0, 'frames per second of the GIF')
    # leg odometry (always run, with and without the IMU): odometry_imu: the odometry the course correction
    # (heading_correction, CourseChoice) uses, and /odom in the bag, has the IMU
    odometry_imu: bool = param(True, 'the odometry the course correction uses (and /odom in the bag) has the IMU')


TRIAL_GROUPS = (GaitChoice, SceneParams, TrialSettings, ReadTime, CourseChoice, LocomotionParams, DetectorConfig)
# where a trial's default differs from the node's: the trials walk the paper's mockup (sim_node: flat)
# in the paper's open loop (locomotion_node: the course correction on) with the paper's swing (locomotion_node:
# a swinging leg that meets an obstacle is lifted higher)
TRIAL_DEFAULTS = {'terrain': 'mockup', 'heading_correction': False, 'obstacle_lift_m': 0.0}
TrialConfig = merged_schema(
    'TrialConfig', TRIAL_GROUPS, __name__,
    'One trial: the parameter fields of ' + ', '.join(g.__name__ for g in TRIAL_GROUPS) + ', by their names.',
    defaults=TRIAL_DEFAULTS)


def locomotion_params(cfg: TrialConfig) -> LocomotionParams:
    """The controller's parameters of a trial (LocomotionParams checks them: LocomotionError names a bad one)."""
    return LocomotionParams(**values(LocomotionParams, cfg))


def detector_config(cfg: TrialConfig) -> DetectorConfig:
    """The detector of a trial (DetectorConfig checks it: DetectorError names a bad value)."""
    return DetectorConfig(**values(DetectorConfig, cfg))


def add_support_margin_option(ap, walks: str) -> None:
    """``--support-margin M``: locomotion_node's ``support_margin_m`` for ``walks``, described and
    defaulted by its declaration."""
    spec = specs(LocomotionParams)['support_margin_m']
    ap.add_argument('--support-margin', type=param_float(spec), default=spec.default, metavar='M',
                    help=f"{walks}: {spec.description} (locomotion_node's support_margin_m)")
