"""Provisioning the real robot's servos: find them on the bus and give each its joint's ID.

AX-12As leave the factory with ID 1 at 1 Mbps, so new servos are connected one at a time and
renumbered to the ID the robot description gives their joint (``bus`` section of robot.yaml:
``id = 3 (leg - 1) + joint index + 1`` unless overridden)::

    servo_tool scan                          # who is on the bus (IDs 0..253)
    servo_tool set-id --from 1 --joint leg3_femur    # -> ID 8
    servo_tool set-id --from 1 --to 8        # the same by number

``set-id`` refuses when the new ID already answers (two servos with one ID garble every reply)
and checks the servo answers under its new ID afterwards. Library functions, no ROS.
"""
from __future__ import annotations

import argparse
import os
import sys

from dynamixel_sdk import COMM_SUCCESS, PacketHandler
from tqdm import tqdm

from hexapod_driver import protocol as p
from hexapod_driver.port import LowLatencyPortHandler
from hexapod_model.cli_common import ArgumentParser, make_parser, nonnegative_int, positive_int
from hexapod_model.description import load_robot


class ServoToolError(RuntimeError):
    """The requested change cannot be made safely; the message says why."""


def open_port(device: str, baud_rate: int, margin_ms: float = 10.0) -> LowLatencyPortHandler:
    if not os.path.exists(device):
        raise ServoToolError(f'{device}: no such device (is the USB adapter plugged in? see docs/real-robot.md)')
    port = LowLatencyPortHandler(device, latency_timer_ms=1.0, margin_ms=margin_ms)
    try:
        ok = port.setBaudRate(baud_rate)
    except Exception as exc:            # noqa: BLE001 - pyserial raises several types for a bad device
        raise ServoToolError(f'cannot open {device}: {exc}') from None
    if not ok:
        raise ServoToolError(f'{device}: baud rate {baud_rate} not supported')
    return port


def model_of(port, packet: PacketHandler, servo_id: int, attempts: int = 2) -> int | None:
    """Model number of the servo answering ``servo_id``, or None if nothing answers."""
    for _ in range(attempts):
        port.is_using = False
        _rx, result, _err = packet.txRxPacket(port, [0, 0, servo_id, 2, p.PING, 0])
        if result != COMM_SUCCESS:
            continue
        data, result, _err = packet.readTxRx(port, servo_id, 0, 2)
        if result == COMM_SUCCESS and len(data) == 2:
            return p.u16(data)
    return None


def scan(port, ids=range(p.MAX_ID + 1), progress: bool = True) -> list[tuple[int, int]]:
    """(id, model number) of every servo answering a PING among ``ids``."""
    packet = PacketHandler(1.0)
    found = []
    for sid in tqdm(list(ids), desc='scanning IDs', unit='id', disable=not progress, leave=False):
        model = model_of(port, packet, sid, attempts=1)
        if model is not None:
            found.append((sid, model))
    return found


def set_id(port, old: int, new: int) -> None:
    """Renumber the servo at ``old`` to ``new`` (EEPROM register 3), with safety checks."""
    for name, v in (('old', old), ('new', new)):
        if not 0 <= v <= p.MAX_ID:
            raise ServoToolError(f'{name} ID must be 0..{p.MAX_ID}, got {v}')
    if old == new:
        raise ServoToolError(f'the servo already has ID {new}')
    packet = PacketHandler(1.0)
    model = model_of(port, packet, old)
    if model is None:
        raise ServoToolError(f'no servo answers at ID {old}')
    other = model_of(port, packet, new)
    if other is not None:
        raise ServoToolError(f'ID {new} is already taken (a servo with model number {other} answers there)')
    port.is_using = False
    result, err = packet.writeTxRx(port, old, 3, 1, [new])
    # the status packet of an ID change may come from either ID; what counts is who answers now
    if model_of(port, packet, new) is None:
        raise ServoToolError(f'servo at ID {old} did not take ID {new} '
                             f'({packet.getTxRxResult(result)} {p.describe_error(err)})')
    if model_of(port, packet, old) is not None:
        raise ServoToolError(f'after renumbering, a servo still answers at ID {old}: more than one was connected')


def main(argv=None) -> int:
    robot = load_robot()
    # the bus options are accepted before or after the sub-command (scan --device X) and listed in
    # every sub-command's --help: one parent parser holds them
    common = ArgumentParser(add_help=False)
    common.add_argument('--device', default='/dev/hexapod_dynamixel', help='serial device (the udev symlink)')
    common.add_argument('--baud', type=positive_int, default=robot.bus.baud_rate,
                        help='baud rate (from the robot description)')
    ap = make_parser('servo_tool', __doc__, parents=[common])
    sub = ap.add_subparsers(dest='cmd', required=True, metavar='{scan,set-id}')
    # SUPPRESS: a sub-command's defaults must not overwrite options given before the sub-command
    quiet_common = ArgumentParser(add_help=False)
    for a in common._actions:
        quiet_common.add_argument(*a.option_strings, type=a.type, default=argparse.SUPPRESS,
                                  help=f'{a.help} (default: {a.default})')
    sc = sub.add_parser('scan', help='list the servos that answer', parents=[quiet_common],
                        description='List the servos that answer a PING (IDs 0..--max-id).')
    sc.add_argument('--max-id', type=nonnegative_int, default=p.MAX_ID, help='highest ID to ping')
    si = sub.add_parser('set-id', help='give the servo at --from a new ID', parents=[quiet_common],
                        description='Give the servo at --from a new ID (refused when the new ID already answers).')
    si.add_argument('--from', dest='old', type=nonnegative_int, default=1, help='current ID (factory: 1)')
    g = si.add_mutually_exclusive_group(required=True)
    g.add_argument('--to', type=nonnegative_int, help='new ID')
    g.add_argument('--joint', help="joint whose ID (from the robot description) to give, e.g. leg3_femur")
    args = ap.parse_args(argv)
    try:
        port = open_port(args.device, args.baud)
        if args.cmd == 'scan':
            found = scan(port, range(min(args.max_id, p.MAX_ID) + 1))
            by_id = {j.servo_id: j.joint for j in robot.bus.joints}
            for sid, model in found:
                kind = 'AX-12A' if model == p.AX12A_MODEL_NUMBER else f'model {model} (not an AX-12A)'
                print(f'id {sid:3d}: {kind:28s} {by_id.get(sid, "(no joint in the robot description)")}')
            missing = sorted(set(by_id) - {sid for sid, _ in found})
            print(f'{len(found)} servo(s) found' + ('; missing: ' + ', '.join(f'{by_id[i]} (id {i})' for i in missing)
                                                  if missing else '; every joint answers'))
        else:
            new = args.to if args.joint is None else robot.bus.by_joint(args.joint).servo_id
            set_id(port, args.old, new)
            print(f'servo at ID {args.old} now has ID {new}' + (f' ({args.joint})' if args.joint else ''))
        port.closePort()
    except (ServoToolError, ValueError) as exc:
        print(f'{ap.prog}: error: {exc}', file=sys.stderr)
        return 1
    return 0


if __name__ == '__main__':
    sys.exit(main())
