"""Benchmark of bag replay: sustained throughput and real-time timing, with a subscriber receiving.

    ./hexapod run hexapod_sim bench_replay [--messages N] [--realtime-s S]

A bag of a 1 kHz /joint_states stream (18 joints per message) is replayed while a subscriber in
a separate process (Python, raw CDR, depth 1000) counts what arrives.
1. Sustained throughput: 2 s (wall) runs at rates 1, 2, 4, 8, 16 (1k..16k msg/s); for each the
   messages/s published and received and the loss; the highest rate with >= 99.9 % received is
   the sustained replay throughput with a subscriber receiving.
2. Publisher only: every deadline already past, the player publishes as fast as it can (the
   subscriber then falls behind and reliable keep-last history drops messages).
Each run prints the publish lateness versus the absolute schedule (median / p95 / max).

DDS stays on loopback (ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST) in its own ROS_DOMAIN_ID.
"""
from __future__ import annotations

import argparse
import multiprocessing as mp
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

from hexapod_model import contract
from hexapod_model.description import ALL_JOINTS
from hexapod_sim.bagio import BagReader, BagWriter

try:
    from tqdm import tqdm
except ImportError:
    tqdm = None


def write_joint_state_bag(path: Path, n: int, period_ns: int = 1_000_000) -> None:
    t0 = 1_000_000_000_000
    joints = list(ALL_JOINTS)
    it = range(n)
    if tqdm:
        it = tqdm(it, desc='writing bench bag', unit='msg', file=sys.stderr)
    with BagWriter(path) as w:
        for i in it:
            t = t0 + i * period_ns
            w.write(contract.JOINT_STATES, contract.MSG_TYPES[contract.JOINT_STATES],
                    {'header': {'stamp': contract.stamp_dict_ns(t)},
                     'name': joints, 'position': [0.001 * i + k for k in range(len(joints))]}, t)


def _subscriber(domain_id: int, expected: int, idle_s: float, ready, out) -> None:
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.qos import QoSProfile
    from sensor_msgs.msg import JointState

    rclpy.init(domain_id=domain_id)
    node = rclpy.create_node('bench_replay_sub')
    got = {'n': 0, 'first': None, 'last': None}

    def cb(_data):
        now = time.monotonic()
        got['n'] += 1
        got['first'] = got['first'] or now
        got['last'] = now

    node.create_subscription(JointState, contract.JOINT_STATES, cb, QoSProfile(depth=1000), raw=True)
    ex = SingleThreadedExecutor()
    ex.add_node(node)
    ready.set()
    deadline = time.monotonic() + 120.0
    while got['n'] < expected and time.monotonic() < deadline:
        ex.spin_once(timeout_sec=0.1)
        if got['last'] is not None and time.monotonic() - got['last'] > idle_s:
            break
    out.put(dict(got))
    node.destroy_node()
    rclpy.try_shutdown()


def _run(bag: Path, rate: float, domain_id: int, label: str, duration_s: float | None = None) -> float:
    import rclpy

    from hexapod_sim.tools.replay import BagPlayer

    reader = BagReader(bag)
    n = reader.message_count if duration_s is None else min(reader.message_count, int(round(duration_s * 1000)))
    ctx = mp.get_context('spawn')
    ready, out = ctx.Event(), ctx.Queue()
    proc = ctx.Process(target=_subscriber, args=(domain_id, n, 2.0, ready, out), daemon=True)
    proc.start()
    ready.wait(30)
    rclpy.init(domain_id=domain_id)
    player = BagPlayer(reader, rate=rate, qos_depth=1000, duration_s=duration_s)
    try:
        if not player.wait_for_subscribers(20.0):
            print(f'{label}: subscriber not discovered within 20 s', file=sys.stderr)
        time.sleep(0.3)
        stats = player.play()
    finally:
        player.destroy_node()
        rclpy.try_shutdown()
    got = out.get(timeout=150)
    proc.join(10)
    rx_span = (got['last'] - got['first']) if got['n'] > 1 else float('nan')
    late = sorted(stats.lateness_s)
    print(f'{label}:')
    print(f'  published {stats.total} msgs in {stats.wall_s:.3f} s = {stats.total / stats.wall_s:,.0f} msg/s')
    print(f'  received  {got["n"]} msgs ({100.0 * got["n"] / max(1, stats.total):.1f} %) over '
          f'{rx_span:.3f} s = {got["n"] / rx_span if rx_span > 0 else float("nan"):,.0f} msg/s')
    if late:
        print(f'  publish lateness vs schedule: median {1e3 * statistics.median(late):.3f} ms, '
              f'p95 {1e3 * late[int(0.95 * (len(late) - 1))]:.3f} ms, max {1e3 * late[-1]:.3f} ms')
    return got['n'] / max(1, stats.total)


def main(args=None) -> int:
    p = argparse.ArgumentParser(prog='bench_replay', description=__doc__.split('\n')[0])
    p.add_argument('--messages', type=int, default=10000, help='messages in the publisher-only run')
    p.add_argument('--rates', type=float, nargs='+', default=[1, 2, 4, 8, 16],
                   help='rate factors of the sustained-throughput sweep (x 1000 msg/s)')
    opts = p.parse_args(args if args is not None else sys.argv[1:])
    os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    domain_id = 140 + os.getpid() % 20
    print(f'bench_replay: ROS_DOMAIN_ID={domain_id}, {os.cpu_count()} CPU(s)')
    with tempfile.TemporaryDirectory(prefix='bench_replay_') as tmp:
        bag = Path(tmp) / 'stream_1khz'
        write_joint_state_bag(bag, int(max(2000 * max(opts.rates), opts.messages)) + 1)
        sustained = 0.0
        for rate in opts.rates:
            frac = _run(bag, rate=rate, domain_id=domain_id, duration_s=2.0 * rate,
                        label=f'rate {rate:g} = {1000 * rate:,.0f} msg/s for 2 s')
            if frac >= 0.999:
                sustained = max(sustained, 1000 * rate)
        _run(bag, rate=1e6, domain_id=domain_id, duration_s=opts.messages / 1000.0,
             label=f'publisher only ({opts.messages} messages, every deadline already past)')
        print(f'sustained replay throughput with a subscriber receiving >= 99.9 %: '
              f'{sustained:,.0f} msg/s (highest rate tried: {1000 * max(opts.rates):,.0f} msg/s)')
    return 0


if __name__ == '__main__':
    sys.exit(main())
