"""The recording and topic contract shared by driver, sim, controller, replay and tools.

Bags are rosbag2-layout MCAP (``metadata.yaml`` + ``.mcap``; ros2msg schemas, CDR). Joint names
are ``leg{1..6}_{coxa,femur,tibia}``; angles are the DH joint variable theta in radians.

``/joint_commands`` (sensor_msgs/msg/JointState): goal positions sent to the servos, one message
per bus write (sync write), ``header.stamp`` = time of the write.
``/joint_states`` (sensor_msgs/msg/JointState): measured positions, one message per bus read
transaction (a single joint), ``header.stamp`` = the time the position was sampled (the start of
the read transaction). Velocity/effort may be filled where measured.

The driver (hardware) and the sim node expose exactly the same topics and services, so the
controller cannot tell them apart.

Names are relative (no leading '/'): a node resolves them in its namespace, so the whole stack runs
under ``--ros-args -r __ns:=/hexa`` (``/hexa/joint_states`` ...) and, without a namespace, they are
the absolute names of before (``/joint_states``). Bags store absolute names (:func:`bag_topic`);
tools that read bags compare :func:`topic_key`, so ``/joint_states`` in a bag recorded before the
names were made relative and ``joint_states`` are the same contract topic.
"""


NS_PER_S = 1_000_000_000


# Stamps: the one conversion between seconds (float) and builtin_interfaces/Time (sec, nanosec).
# Bags and messages alike use these, so a stamp written and read back is the same number everywhere.

def stamp_parts(t_s: float) -> tuple[int, int]:
    """(sec, nanosec) of a header stamp for a time in seconds (rounded to whole nanoseconds)."""
    return stamp_parts_ns(int(round(t_s * 1e9)))


def stamp_parts_ns(t_ns: int) -> tuple[int, int]:
    """(sec, nanosec) of a header stamp for a time in integer nanoseconds (bag record times)."""
    return divmod(int(t_ns), NS_PER_S)


def stamp_dict(t_s: float) -> dict:
    """A stamp as the plain mapping bag writers take: ``{'sec': ..., 'nanosec': ...}``."""
    return stamp_dict_ns(int(round(t_s * 1e9)))


def stamp_dict_ns(t_ns: int) -> dict:
    """The plain-mapping stamp of a time in integer nanoseconds."""
    sec, nanosec = stamp_parts_ns(t_ns)
    return {'sec': sec, 'nanosec': nanosec}


def stamp_msg(t_s: float):
    """A ``builtin_interfaces/msg/Time`` for a time in seconds."""
    from builtin_interfaces.msg import Time
    sec, nanosec = stamp_parts(t_s)
    return Time(sec=sec, nanosec=nanosec)


def stamp_seconds(stamp) -> float:
    """Seconds of a stamp: a Time message (or anything with ``sec``/``nanosec``) or a plain mapping."""
    if isinstance(stamp, dict):
        return float(stamp['sec']) + float(stamp['nanosec']) * 1e-9
    return float(stamp.sec) + float(stamp.nanosec) * 1e-9


def stamp_ns(stamp) -> int:
    """Integer nanoseconds of a stamp (exact; for comparing stamps with bag record times)."""
    if isinstance(stamp, dict):
        return int(stamp['sec']) * NS_PER_S + int(stamp['nanosec'])
    return int(stamp.sec) * NS_PER_S + int(stamp.nanosec)


JOINT_COMMANDS = 'joint_commands'           # sensor_msgs/msg/JointState, in
JOINT_STATES = 'joint_states'               # sensor_msgs/msg/JointState, out, one per read
READ_SCHEDULE = 'read_schedule'             # hexapod_msgs/msg/ReadSchedule, in
SET_READ_SCHEDULE = 'set_read_schedule'     # hexapod_msgs/srv/SetReadSchedule: the same, acknowledged
SERVO_DIAGNOSTICS = 'servo_diagnostics'     # hexapod_msgs/msg/ServoDiagnostics, out, periodic
BUS_TIMING = 'bus_timing'                   # hexapod_msgs/msg/BusTiming, out, periodic
EMERGENCY_STOP = 'emergency_stop'           # std_srvs/srv/Trigger: torque off on every servo
POWER = 'power'                             # sensor_msgs/msg/BatteryState (sim: battery model)
IMU = 'imu'                                 # sensor_msgs/msg/Imu (sim only; the method needs none)
# /clock stays absolute: rclpy's use_sim_time subscribes to /clock, whatever the node's namespace.
CLOCK = '/clock'                            # rosgraph_msgs/msg/Clock (sim, replay)
GROUND_DETECTION = 'ground_detection'       # hexapod_msgs/msg/LegGroundDetection (controller)
SWING_DOWN = 'swing_down'                   # hexapod_msgs/msg/SwingDownStart (controller)
TERRAIN = 'terrain'                         # hexapod_msgs/msg/TerrainClass (terrain_node), once per gait cycle
CMD_VEL = 'cmd_vel'                         # geometry_msgs/msg/Twist (controller input)
ODOM = 'odom'                               # nav_msgs/msg/Odometry (controller: leg odometry, odom -> base_link)
PREDICT_SWING_DOWN = 'predict_swing_down'   # hexapod_msgs/srv/PredictSwingDown (model node)
ROBOT_DESCRIPTION = 'robot_description'     # std_msgs/msg/String, the URDF, transient local (sim, robot_state)
# tf and diagnostics keep the absolute names the ROS tools listen on (remap them for a namespaced robot)
TF = '/tf'                                  # tf2_msgs/msg/TFMessage: world -> base_link, base_link -> links
TF_STATIC = '/tf_static'                    # tf2_msgs/msg/TFMessage: the fixed joints, transient local
DIAGNOSTICS = '/diagnostics'                # diagnostic_msgs/msg/DiagnosticArray: per servo + bus health
# Evaluation-only ground truth published by the sim; never consumed by any estimator/controller.
SIM_TRUTH_CONTACTS = 'sim/foot_contacts'    # hexapod_msgs-free: std_msgs/msg/Float64MultiArray
SIM_TRUTH_POSE = 'sim/body_pose'            # geometry_msgs/msg/PoseStamped
# What the simulated robot walks on (terrain, seed, start position; YAML text), once, transient local:
# the sim-vs-real tool replays a simulated walk on the same ground.
SIM_SCENE = 'sim/scene'                     # std_msgs/msg/String


def topic_key(name: str) -> str:
    """The contract name of a topic as written anywhere: '/joint_states' and 'joint_states' are one topic."""
    return name.lstrip('/')


def bag_topic(name: str) -> str:
    """The name a bag stores for a contract topic: absolute, as rosbag2 records it ('/joint_states')."""
    return '/' + topic_key(name)

MSG_TYPES = {
    JOINT_COMMANDS: 'sensor_msgs/msg/JointState',
    JOINT_STATES: 'sensor_msgs/msg/JointState',
    READ_SCHEDULE: 'hexapod_msgs/msg/ReadSchedule',
    SERVO_DIAGNOSTICS: 'hexapod_msgs/msg/ServoDiagnostics',
    BUS_TIMING: 'hexapod_msgs/msg/BusTiming',
    POWER: 'sensor_msgs/msg/BatteryState',
    IMU: 'sensor_msgs/msg/Imu',
    CLOCK: 'rosgraph_msgs/msg/Clock',
    GROUND_DETECTION: 'hexapod_msgs/msg/LegGroundDetection',
    SWING_DOWN: 'hexapod_msgs/msg/SwingDownStart',
    TERRAIN: 'hexapod_msgs/msg/TerrainClass',
    CMD_VEL: 'geometry_msgs/msg/Twist',
    ODOM: 'nav_msgs/msg/Odometry',
    SIM_TRUTH_CONTACTS: 'std_msgs/msg/Float64MultiArray',
    SIM_TRUTH_POSE: 'geometry_msgs/msg/PoseStamped',
    SIM_SCENE: 'std_msgs/msg/String',
    ROBOT_DESCRIPTION: 'std_msgs/msg/String',
    TF: 'tf2_msgs/msg/TFMessage',
    TF_STATIC: 'tf2_msgs/msg/TFMessage',
    DIAGNOSTICS: 'diagnostic_msgs/msg/DiagnosticArray',
}
