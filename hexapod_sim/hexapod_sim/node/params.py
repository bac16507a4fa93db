"""The sim node's parameters (:mod:`hexapod_model.param_schema`): type, default, description and
allowed values in one place, read by the node, its ``--params-file`` and the launch-file test.
No ROS import."""
from __future__ import annotations

from dataclasses import dataclass

from hexapod_model.param_schema import NodeSpec, ReadTime, RobotSource, param
from hexapod_sim.node.live import DEFAULT_PORT as DEFAULT_LIVE_PORT
from hexapod_sim.physics.plant import DEFAULT_AMBIENT_C, DEFAULT_START_TEMPERATURE_C
from hexapod_sim.physics.scene_params import SceneParams


@dataclass(frozen=True)
class SimParams:
    """The simulation's own parameters; the scene's are :class:`SceneParams`, the read time
    :class:`~hexapod_model.param_schema.ReadTime` (see :data:`NODE`)."""

    t_write_s: float = param(0.0, 'duration of one sync write [s]', min=0.0)
    fixed_base: bool = param(False, 'weld the trunk in the air with no ground (calibration stand, free swing)')
    real_time_factor: float = param(1.0, 'simulated seconds per wall second; 0 = as fast as possible; '
                                    'ignored in lockstep; may change at run time', min=0.0, read_only=False)
    lockstep: bool = param(False, 'advance one read-schedule cycle per /joint_commands message (deterministic runs)')
    record: str = param('', "bag to record every topic to: '' off, 'auto' bags/sim_<time>, a name (bags/<name>) "
                        'or a path')
    stop_on_record_error: bool = param(False, 'when a write to the bag fails (disk full, file-size limit): '
                                       'true = stop: torque off on every servo and the node ends (exit code '
                                       '1); false = the robot runs on unrecorded')
    imu_rate_hz: float = param(400.0, 'IMU rate [Hz] (paper: 400); 0 = no IMU; at most one sample per physics '
                               'step', min=0.0)
    power_rate_hz: float = param(100.0, '/power rate [Hz] (power averaged); 0 off', min=0.0)
    diagnostics_rate_hz: float = param(10.0, '/servo_diagnostics rate [Hz]; 0 off', min=0.0)
    bus_timing_rate_hz: float = param(1.0, '/bus_timing rate [Hz]; 0 off', min=0.0)
    truth_rate_hz: float = param(100.0, 'rate of the evaluation-only truth topics sim/foot_contacts, '
                                 'sim/body_pose [Hz]; 0 off', min=0.0)
    truth_out: str = param('', "benchmarks: keep body position and foot contacts per ms of physics and write them to "
                           "this .npz file at exit (hexapod_sim.physics.truth_log; not published, so it does not load the "
                           "graph); '' off")
    clock_rate_hz: float = param(1000.0, '/clock rate in simulated time [Hz]; 0 off', min=0.0)
    ambient_temperature_c: float = param(DEFAULT_AMBIENT_C, 'ambient temperature [C]')
    initial_temperature_c: float = param(DEFAULT_START_TEMPERATURE_C, 'servo temperature at start [C]')
    foxglove: bool = param(False, 'serve a Foxglove WebSocket live view (robot model, TF, joint states, ground '
                           'detection) on 127.0.0.1')
    foxglove_port: int = param(DEFAULT_LIVE_PORT, 'port of the Foxglove live view (0 = any free port)', min=0, max=65535)

    @staticmethod
    def period(rate_hz: float) -> float:
        """Period [s] of a rate parameter; 0 Hz = off (period 0)."""
        return 1.0 / rate_hz if rate_hz > 0 else 0.0


NODE = NodeSpec('hexapod_sim', 'sim_node', 'sim_node', (RobotSource, SceneParams, ReadTime, SimParams))
