"""Benchmark: position reads through the real driver core against the bus emulator.

Starts the emulator in its own process (as a separate device would be), runs the driver's bus
loop over the default 18-joint schedule and prints reads per second and T_com (mean, median,
99th percentile) next to the theoretical wire time of one read at the configured baud rate:
instruction 8 bytes + status 8 bytes (2 data bytes), 10 bits per byte, plus the return delay.

Two runs: ``software`` (the emulator answers as fast as it can: T_com is pure host/driver
overhead) and ``wire`` (the emulator holds each reply back by the wire time, as a real 1 Mbps bus
would: T_com should approach wire time + overhead).

Both processes stamp with the same wall clock, so each wire-mode read is split into its parts: the
transport from the driver's write to the emulator (the pseudo-terminal, where a real bus has the
USB adapter), the servo's time (wire time + return delay, held by the emulator), the transport back,
and what is left: the driver's own overhead.
"""
from __future__ import annotations

import argparse
import multiprocessing
import os
import pty
import select
import subprocess
import sys
import tempfile
import time
import tty

import numpy as np
from tqdm import tqdm

from hexapod_driver import protocol as p
from hexapod_driver.bus import DynamixelBus
from hexapod_driver.config import DriverConfig
from hexapod_model.description import load_robot


def _start_emulator(wire_time: bool, robot_path: str | None, timing_out: str) -> tuple[subprocess.Popen, str]:
    cmd = [sys.executable, '-m', 'hexapod_driver.emulator', '--timing-out', timing_out]
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


def split_round_trips(stamps: np.ndarray, t_com: np.ndarray, emulator: np.ndarray) -> dict:
    """Medians of (up, servo, down) [s] per read: ``stamps`` are the driver's write times, ``t_com`` the
    read durations, ``emulator`` the (arrival, reply) wall times of the emulator's answered instructions.
    up + servo + down = T_com: the driver's own work is inside up (writing) and down (waking, parsing)."""
    arrival, reply = emulator[:, 0], emulator[:, 1]
    k = np.searchsorted(arrival, stamps)
    ok = k < len(arrival)
    k, s, d = k[ok], stamps[ok], t_com[ok]
    same = arrival[k] < s + d                    # the first arrival after the write belongs to this read
    k, s, d = k[same], s[same], d[same]
    up, servo, down = arrival[k] - s, reply[k] - arrival[k], s + d - reply[k]
    return dict(up=float(np.median(up)), servo=float(np.median(servo)), down=float(np.median(down)),
                matched=int(len(k)))


def _echo(fd: int) -> None:
    while True:
        select.select([fd], [], [])
        data = os.read(fd, 64)
        if data == b'q':
            return
        os.write(fd, data)


def pty_round_trip(n: int = 2000, size: int = 8) -> float:
    """Median round trip [s] of ``size`` bytes through a bare pseudo-terminal to an echoing process and
    back, both sides waiting in select(): the transport cost with no driver and no emulator work."""
    master, slave = pty.openpty()
    tty.setraw(master)
    tty.setraw(slave)
    child = multiprocessing.get_context('fork').Process(target=_echo, args=(master,), daemon=True)
    child.start()
    msg, rt = b'\x55' * size, []
    try:
        for _ in range(n):
            t0 = time.perf_counter()
            os.write(slave, msg)
            got = 0
            while got < size:
                select.select([slave], [], [])
                got += len(os.read(slave, 64))
            rt.append(time.perf_counter() - t0)
        os.write(slave, b'q')
        child.join(timeout=5)
    finally:
        if child.is_alive():
            child.kill()
        os.close(master)
        os.close(slave)
    return float(np.median(rt))


def run(mode: str, n_reads: int, robot, robot_path, return_delay: int) -> dict:
    fd, timing_out = tempfile.mkstemp(suffix='.npy', prefix='bench_driver_')
    os.close(fd)
    proc, port = _start_emulator(mode == 'wire', robot_path, timing_out)
    try:
        bus = DynamixelBus(robot, DriverConfig(device=port, return_delay_time=return_delay,
                                               diagnostics_period_s=1e9, command_timeout_s=0.0))
        bus.start()
        bus.timing.snapshot(reset=True)
        t_com, stamps = [], []
        t0 = time.perf_counter()
        with tqdm(total=n_reads, desc=f'{mode:8s} reads', unit='read', leave=False) as bar:
            while len(t_com) < n_reads:
                res = bus.step()
                t_com += [s.t_com_s for s in res.samples]
                stamps += [s.stamp for s in res.samples]
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
        proc.terminate()
        proc.wait(timeout=5)
        emulator = np.load(timing_out)
    finally:
        if proc.poll() is None:
            proc.kill()
        os.unlink(timing_out)
    t = np.asarray(t_com)
    return dict(mode=mode, reads=len(t), reads_per_s=len(t) / elapsed, mean=t.mean(), p50=np.median(t),
                p99=np.percentile(t, 99), max=t.max(), failed=snap.failed_reads, write=float(np.median(tw)),
                split=split_round_trips(np.asarray(stamps), t, emulator))


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
            sp = r['split']
            print(f'wire mode: mean T_com {r["mean"] * 1e6:.0f} us = wire time {wire * 1e6:.0f} us + '
                  f'{(r["mean"] - wire) * 1e6:.0f} us host/driver overhead; median T_com {r["p50"] * 1e6:.0f} us '
                  f'= {r["p50"] / wire:.2f} x wire time')
            rt = pty_round_trip()
            driver = sp['up'] + sp['down'] - rt
            print(f'  median split of {sp["matched"]} reads (one wall clock in both processes): driver write -> '
                  f'emulator {sp["up"] * 1e6:.0f} us, servo {sp["servo"] * 1e6:.0f} us (wire time + return delay, '
                  f'held by the emulator), emulator -> driver {sp["down"] * 1e6:.0f} us')
            print(f'  a bare pseudo-terminal round trip (8 bytes, echo process, no work) takes {rt * 1e6:.0f} us here; '
                  f'the rest of the two transports, {driver * 1e6:.0f} us, is the driver and emulator code')
            print(f'  T_com less the pseudo-terminal (a bus with a zero-latency adapter): {(r["p50"] - rt) * 1e6:.0f} us '
                  f'= {(r["p50"] - rt) / wire:.2f} x wire time')
    return 0


if __name__ == '__main__':
    sys.exit(main())
