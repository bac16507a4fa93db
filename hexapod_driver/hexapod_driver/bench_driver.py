"""Benchmark: position reads through the real driver core against the bus emulator.

Starts the emulator in its own process (as a separate device would be), runs the driver's bus
loop over the default 18-joint schedule and prints reads per second and T_com (mean, median,
99th percentile) next to the theoretical wire time of one read at the configured baud rate:
instruction 8 bytes + status 8 bytes (2 data bytes), 10 bits per byte, plus the return delay.

Two runs: ``software`` (the emulator answers as fast as it can: T_com is pure host/driver
overhead) and ``wire`` (the emulator holds each reply back by the wire time, as a real 1 Mbps bus
would: T_com should approach wire time + overhead).
"""
from __future__ import annotations

import argparse
import subprocess
import sys
import time

import numpy as np
from tqdm import tqdm

from hexapod_model.description import load_robot

from . import protocol as p
from .config import DriverConfig
from .dynamixel_bus import DynamixelBus


def _start_emulator(wire_time: bool, robot_path: str | None) -> tuple[subprocess.Popen, str]:
    cmd = [sys.executable, '-m', 'hexapod_driver.emulator']
    if wire_time:
        cmd.append('--wire-time')
    if robot_path:
        cmd += ['--robot', robot_path]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, text=True)
    line = proc.stdout.readline()
    if ' on ' not in line:
        proc.kill()
        raise RuntimeError(f'bus emulator did not start: {line!r}')
    return proc, line.rsplit(' on ', 1)[1].strip()


def run(mode: str, n_reads: int, robot, robot_path, return_delay: int) -> dict:
    proc, port = _start_emulator(mode == 'wire', robot_path)
    try:
        bus = DynamixelBus(robot, DriverConfig(device=port, return_delay_time=return_delay,
                                               diagnostics_period_s=1e9, command_timeout_s=0.0))
        bus.start()
        bus.timing.snapshot(reset=True)
        t_com = []
        t0 = time.perf_counter()
        with tqdm(total=n_reads, desc=f'{mode:8s} reads', unit='read', leave=False) as bar:
            while len(t_com) < n_reads:
                res = bus.step()
                t_com += [s.t_com_s for s in res.samples]
                bar.update(len(res.samples))
        elapsed = time.perf_counter() - t0
        snap = bus.timing.snapshot(reset=True)
        goals = {j: 0.0 for j in bus.joints}
        tw = []
        for _ in range(200):
            a = time.perf_counter()
            bus.sync_write(goals)
            tw.append(time.perf_counter() - a)
        bus.close()
    finally:
        proc.terminate()
        proc.wait(timeout=5)
    t = np.asarray(t_com)
    return dict(mode=mode, reads=len(t), reads_per_s=len(t) / elapsed, mean=t.mean(), p50=np.median(t),
                p99=np.percentile(t, 99), max=t.max(), failed=snap.failed_reads, write=float(np.median(tw)))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog='bench_driver', description=__doc__.split('\n\n')[0])
    ap.add_argument('--reads', type=int, default=5000, help='position reads per run')
    ap.add_argument('--robot', default=None, help='robot description YAML (default: packaged)')
    ap.add_argument('--return-delay', type=int, default=0, help='return delay time register (x 2 us) to configure')
    ap.add_argument('--modes', nargs='+', default=['software', 'wire'], choices=['software', 'wire'])
    args = ap.parse_args(argv)
    if args.reads < 100:
        ap.error(f'--reads must be >= 100 for a meaningful 99th percentile, got {args.reads}')
    robot = load_robot(args.robot)
    baud = robot.bus.baud_rate
    wire = p.read_bus_time_s(2, baud, args.return_delay * p.RETURN_DELAY_UNIT_S)
    tx, rx = p.read_transaction_bytes(2)
    print(f'theoretical bus time of one position read at {baud / 1e6:g} Mbps: ({tx} + {rx} bytes) x '
          f'{p.BITS_PER_BYTE} bits + return delay {args.return_delay * 2} us = {wire * 1e6:.0f} us '
          f'-> bus limit {1 / wire:.0f} reads/s')
    print(f'robot description T_com (paper, hardware-accelerated USB): {robot.bus.t_com_s * 1e3:g} ms')
    rows = [run(m, args.reads, robot, args.robot, args.return_delay) for m in args.modes]
    print(f'{"mode":9s} {"reads/s":>9s} {"mean":>8s} {"p50":>8s} {"p99":>8s} {"max":>8s} {"failed":>6s} '
          f'{"sync wr":>8s}  of bus limit   (sync wr = median of 200 18-servo SYNC_WRITEs)')
    for r in rows:
        print(f'{r["mode"]:9s} {r["reads_per_s"]:9.0f} {r["mean"] * 1e6:6.0f}us {r["p50"] * 1e6:6.0f}us '
              f'{r["p99"] * 1e6:6.0f}us {r["max"] * 1e6:6.0f}us {r["failed"]:6d} {r["write"] * 1e6:6.0f}us  '
              f'{r["reads_per_s"] * wire * 100:5.1f} %')
    for r in rows:
        if r['mode'] == 'wire':
            print(f'wire mode: mean T_com {r["mean"] * 1e6:.0f} us = wire time {wire * 1e6:.0f} us + '
                  f'{(r["mean"] - wire) * 1e6:.0f} us host/driver overhead')
    return 0


if __name__ == '__main__':
    sys.exit(main())
