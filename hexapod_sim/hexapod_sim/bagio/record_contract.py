"""Record the driver's topics into a contract bag: the `ros2 bag record` stand-in where rosbag2 is missing.

Subscribes to /joint_commands and /joint_states (sensor_msgs/JointState, the recording contract of
hexapod_model/contract.py) and writes every message to a rosbag2-layout MCAP bag, with the
receive time on the node's clock as the log time and the message's own header stamp untouched (the
discrepancy tool compares the two to find stamp glitches). Runs until --duration has passed or
Ctrl-C / SIGTERM, then closes the bag (a killed recorder still leaves a readable bag without its
last second). Then: `./hexapod discrepancy BAG`. Also accepts --ros-args (remaps, use_sim_time).
"""
from __future__ import annotations

import signal
import sys
import threading
from pathlib import Path

from hexapod_model.cli_common import make_parser, new_directory, nonnegative_float


def build_parser():
    ap = make_parser('record_contract', __doc__)
    ap.add_argument('--out', required=True, metavar='BAG', type=new_directory,
                    help='bag directory to write (must not exist yet)')
    ap.add_argument('--duration', type=nonnegative_float, default=0.0, metavar='S',
                    help='stop after this many seconds (0: until Ctrl-C or SIGTERM)')
    return ap


def joint_state_plain(msg) -> dict:
    """sensor_msgs/JointState as the plain dict the bag writer encodes."""
    return {'header': {'stamp': {'sec': int(msg.header.stamp.sec), 'nanosec': int(msg.header.stamp.nanosec)},
                       'frame_id': str(msg.header.frame_id)},
            'name': list(msg.name), 'position': [float(x) for x in msg.position],
            'velocity': [float(x) for x in msg.velocity], 'effort': [float(x) for x in msg.effort]}


def main(argv=None) -> int:
    argv = list(sys.argv if argv is None else ['record_contract', *argv])
    ap = build_parser()
    import rclpy
    from rclpy._rclpy_pybind11 import RCLError
    from rclpy.utilities import remove_ros_args
    try:
        user = remove_ros_args(argv)[1:]
    except RCLError as exc:
        ap.error(f'bad --ros-args: {str(exc).splitlines()[0]}')
    args = ap.parse_args(user)
    out = Path(args.out)

    from rclpy.executors import SingleThreadedExecutor
    from rclpy.qos import QoSProfile
    from rclpy.signals import SignalHandlerOptions
    from sensor_msgs.msg import JointState

    from hexapod_model import contract
    from hexapod_sim.bagio import BagWriter

    stop = threading.Event()
    old = {s: signal.signal(s, lambda *_: stop.set()) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        rclpy.init(args=argv, signal_handler_options=SignalHandlerOptions.NO)
    except RCLError as exc:
        ap.error(f'bad --ros-args: {str(exc).splitlines()[0]}')
    node = rclpy.create_node('record_contract')
    writer = BagWriter(str(out))
    counts = {contract.JOINT_COMMANDS: 0, contract.JOINT_STATES: 0}

    def sink(topic):
        def cb(msg):
            writer.write(topic, contract.MSG_TYPES[topic], joint_state_plain(msg), node.get_clock().now().nanoseconds)
            counts[topic] += 1
        return cb

    qos = QoSProfile(depth=1000)
    subs = [node.create_subscription(JointState, topic, sink(topic), qos) for topic in counts]
    ex = SingleThreadedExecutor()
    ex.add_node(node)
    t_end = None if args.duration == 0 else node.get_clock().now().nanoseconds + int(args.duration * 1e9)
    print(f'recording {", ".join(counts)} into {out} '
          f'({"until Ctrl-C" if t_end is None else f"for {args.duration:g} s"})', file=sys.stderr, flush=True)
    try:
        while not stop.is_set() and rclpy.ok():
            ex.spin_once(timeout_sec=0.1)
            if t_end is not None and node.get_clock().now().nanoseconds >= t_end:
                break
    finally:
        for s in subs:
            node.destroy_subscription(s)
        writer.close()
        ex.shutdown()
        node.destroy_node()
        rclpy.try_shutdown()
        for s, h in old.items():
            signal.signal(s, h)
    print(f'wrote {out}: ' + ', '.join(f'{n} on {t}' for t, n in counts.items())
          + f'; next: ./hexapod discrepancy {out}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
