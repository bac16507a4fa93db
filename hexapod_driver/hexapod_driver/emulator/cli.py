"""``bus_emulator``: an emulated AX-12A bus on a pseudo-terminal until Ctrl-C or SIGTERM."""
from __future__ import annotations

import argparse
import gc
import signal
import sys
import threading

import numpy as np

from hexapod_driver import protocol as p
from hexapod_driver.emulator.backends import BACKEND_GROUP, backend_plugins
from hexapod_driver.emulator.fault_schedule import ReplyRecorder, ScheduleError, ScheduleRunner, load_schedule, servo_registers
from hexapod_driver.emulator.pty_server import BusEmulator
from hexapod_model.cli_common import ArgumentParser, existing_file, nonnegative_float, output_file
from hexapod_model.description import DescriptionError, load_robot


def _load_plugins(ap: argparse.ArgumentParser) -> dict:
    """{name: plug-in object} of the installed backend plug-ins; a broken one is a one-line error."""
    plugins = {}
    for name, ep in sorted(backend_plugins().items()):
        try:
            plugins[name] = ep.load()
        except Exception as exc:                # an installed but broken plug-in: say which and why
            ap.error(f'emulator backend plug-in {name!r} ({ep.value}) does not load: {type(exc).__name__}: {exc}')
    return plugins


def _parser() -> tuple[argparse.ArgumentParser, dict]:
    """The command line, with the options of every installed backend plug-in; (parser, plug-ins)."""
    ap = ArgumentParser(       # usage errors are one line
        prog='bus_emulator',
        description='Emulated AX-12A bus (Dynamixel Protocol 1.0) on a pseudo-terminal: prints the port path,\n'
                    'serves until Ctrl-C. Point the driver at it:\n'
                    '  ros2 run hexapod_driver driver_node --ros-args -p device:=<path>')
    ap.add_argument('--robot', default=None, type=existing_file, help='robot description YAML (default: the packaged robot.yaml)')
    ap.add_argument('--link', default=None, type=output_file(),
                    help='also create this symlink to the pty (a stable name, like a udev symlink)')
    plugins = _load_plugins(ap)
    ap.add_argument('--backend', default='ideal', metavar='NAME',
                    help='what moves the servos. ideal: they move straight to their goals' +
                         ''.join(f'; {name}: {plugin.help}' for name, plugin in plugins.items()) +
                         f' (more backends are plug-ins in the entry-point group {BACKEND_GROUP})')
    for name, plugin in plugins.items():
        plugin.add_arguments(ap.add_argument_group(f'{name} backend'))
    ap.add_argument('--wire-time', action='store_true',
                    help='delay replies by the 1 Mbps wire time of both packets (10 bits/byte)')
    ap.add_argument('--absent', type=int, nargs='*', default=[], help='servo IDs that are not on the bus')
    ap.add_argument('--drop-probability', type=nonnegative_float, default=0.0, help='lose each reply with this probability')
    ap.add_argument('--corrupt-probability', type=nonnegative_float, default=0.0,
                    help='corrupt the checksum of each reply with this probability')
    ap.add_argument('--reply-latency-ms', type=nonnegative_float, default=0.0,
                    help='hold every reply back this long, like an FTDI adapter with its 16 ms default latency timer')
    ap.add_argument('--servo-baud', type=int, default=None,
                    help='baud rate register (address 4) of every servo, e.g. 34 for 57600 baud; a servo answers '
                         'only when the port is opened at its rate')
    ap.add_argument('--status-return-level', type=int, choices=[0, 1, 2], default=None,
                    help='status return level (address 16) of every servo: 0 PING only, 1 reads only, 2 all')
    ap.add_argument('--seed', type=int, default=0, help='seed of the random faults')
    ap.add_argument('--verbose', action='store_true', help='print every instruction packet (slow)')
    ap.add_argument('--timing-out', default=None, metavar='FILE.npy', type=output_file(),
                    help='at exit, write the wall-clock arrival and reply times of every answered instruction '
                         '(an N x 2 array, time.time() seconds) still in the log (last 100000), for benchmarks '
                         'that split a round trip into transport and servo time')
    ap.add_argument('--fault-schedule', default=None, metavar='FILE.json',
                    help='faults that come and go (hexapod_driver.emulator.fault_schedule): their times count '
                         'from the first SIGUSR1 the emulator receives')
    ap.add_argument('--events-out', default=None, metavar='FILE.jsonl', type=output_file(),
                    help='append one JSON line per fault start and end, and at exit the servos\' torque registers')
    ap.add_argument('--replies-out', default=None, metavar='FILE.bin', type=output_file(),
                    help='append every present position a servo reported (float64 rows: wall time, id, tick)')
    return ap, plugins


def _parse(argv) -> tuple[argparse.Namespace, dict, list, object]:
    """(arguments, backend plug-ins, fault schedule, robot); a bad argument is a one-line usage error."""
    ap, plugins = _parser()
    args, unknown = ap.parse_known_args(argv)
    if args.backend != 'ideal' and args.backend not in plugins:
        ap.error(f"--backend {args.backend}: no such backend installed (installed: {', '.join(['ideal', *plugins])}); "
                 f"backends are plug-ins in the entry-point group {BACKEND_GROUP}, e.g. 'sim' (MuJoCo) "
                 f"comes with the hexapod_sim package")
    if unknown:
        ap.error(f"unrecognized arguments: {' '.join(unknown)}")
    for name in ('drop_probability', 'corrupt_probability'):
        v = getattr(args, name)
        if not 0.0 <= v <= 1.0:
            ap.error(f'--{name.replace("_", "-")} must be within 0..1, got {v}')
    if args.timing_out and not args.timing_out.endswith('.npy'):
        ap.error(f'--timing-out {args.timing_out}: must name a .npy file')
    if args.servo_baud is not None and not 0 <= args.servo_baud <= 254:
        ap.error(f'--servo-baud is register 4 (0..254), got {args.servo_baud}')
    try:
        schedule = load_schedule(args.fault_schedule) if args.fault_schedule else []
    except ScheduleError as exc:
        ap.error(f'--fault-schedule {exc}')
    try:
        robot = load_robot(args.robot)
    except DescriptionError as exc:
        ap.error(str(exc))
    return args, plugins, schedule, robot


def _emulator(args: argparse.Namespace, robot, backend) -> BusEmulator:
    """The emulator the arguments describe: its faults and the servos' registers set, not started."""
    # the transaction log is read by --verbose (as it goes) and --timing-out (at exit); kept short
    # otherwise, as 100,000 entries are 100,000 objects for the garbage collector to traverse
    emu = BusEmulator(robot, backend, link_path=args.link, wire_time=args.wire_time, absent_ids=tuple(args.absent),
                      seed=args.seed, log_size=100_000 if args.timing_out else 20_000 if args.replies_out else 1_000)
    if args.drop_probability:
        emu.faults.drop_replies(count=None, probability=args.drop_probability)
    if args.corrupt_probability:
        emu.faults.corrupt_replies(count=None, probability=args.corrupt_probability)
    emu.faults.set_reply_latency(args.reply_latency_ms / 1000.0)
    for s in emu.servos:
        if args.servo_baud is not None:
            s.set_register('baud_rate', args.servo_baud)
        if args.status_return_level is not None:
            s.set_register('status_return_level', args.status_return_level)
    return emu


def _serve(emu: BusEmulator, verbose: bool) -> None:
    """Until SIGTERM or Ctrl-C; with ``verbose`` every instruction packet is printed."""
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    try:
        while not stop.wait(0.2):
            while verbose and emu.log:
                e = emu.log.popleft()
                print(f'{e.t:10.4f} id={e.servo_id:3d} {p.INSTRUCTION_NAMES.get(e.instruction, hex(e.instruction))}'
                      f' addr={e.address} data={e.data.hex(" ")} err={e.error:#04x}'
                      f'{" reply=" + e.reply_params.hex(" ") if e.replied else " (no reply: " + e.note + ")"}'
                      f' rx={e.rx.hex(" ")} tx={e.tx.hex(" ")}', flush=True)
    except KeyboardInterrupt:
        pass


def main(argv=None) -> int:
    args, plugins, schedule, robot = _parse(argv)
    backend = None if args.backend == 'ideal' else plugins[args.backend].create(robot, args)
    emu = _emulator(args, robot, backend)
    # What start-up made (the robot model, a backend's physics and compiled code) is moved out of the
    # garbage collector's reach, as the locomotion node does: a full collection over it held the
    # interpreter 64-107 ms now and then, the replies of that time missed the driver's timeout, and
    # its retries stalled a swing-down between a goal write and the reads (a real servo never pauses).
    gc.freeze()
    emu.start()
    runner = ScheduleRunner(emu, schedule, args.events_out) if (schedule or args.events_out) else None
    replies = ReplyRecorder(emu, args.replies_out) if args.replies_out else None
    if runner is not None:
        signal.signal(signal.SIGUSR1, lambda *_: runner.begin())
    ids = sorted(s.servo_id for s in emu.servos)
    print(f'AX-12A bus emulator: {len(ids)} servos (ids {ids}) on {emu.port}', flush=True)
    if args.link:
        print(f'pty: {emu._slave_name}', flush=True)
    try:
        _serve(emu, args.verbose)
    finally:
        if runner is not None:
            runner.stop()
        if replies is not None:
            replies.close()
        emu.stop()
        if runner is not None:
            runner.close(servo_registers(emu))
        print(f'served {emu.packets} packets', file=sys.stderr)
        if args.timing_out:
            np.save(args.timing_out, np.array([(e.wall, e.wall_reply) for e in emu.log if e.replied],
                                              dtype=float).reshape(-1, 2))
        close = getattr(backend, 'close', None)      # a plug-in's backend may have results to write
        if close is not None:
            close()
    return 0


if __name__ == '__main__':
    sys.exit(main())
