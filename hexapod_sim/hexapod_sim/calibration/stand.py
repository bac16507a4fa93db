"""Run the stand calibration routine on the robot through the driver and write the contract bag.

Put the robot on a stand (trunk fixed, feet free: no leg may touch anything). The routine
(hexapod_sim/calibration/plan.py, about one minute at --speed-scale 1) moves every joint through
the conditions in which the discrepancy tool's candidate effects show, reading the moving joints
as fast as the bus allows; the recording is written as a contract bag for
`./hexapod discrepancy BAG`. The driver verifies and configures all servos first and turns the
torque off at the end. The first time on a robot, keep the default --speed-scale 0.5.
"""
from __future__ import annotations

import sys
from pathlib import Path

from hexapod_model.cli_common import (
    add_no_progress_option,
    add_overlay_option,
    existing_file,
    make_parser,
    new_directory,
    positive_float,
)


def build_parser():
    from hexapod_model.description import LEGS
    from hexapod_sim.calibration.plan import PHASES
    ap = make_parser('stand_calibration', __doc__)
    ap.add_argument('--device', default='/dev/hexapod_dynamixel', help='serial device of the Dynamixel bus')
    ap.add_argument('--out', required=True, metavar='BAG', type=new_directory,
                    help='bag directory to write (must not exist yet)')
    ap.add_argument('--speed-scale', type=positive_float, default=0.5,
                    help='speed of the routine relative to the benchmark routine (1 = about one minute)')
    ap.add_argument('--legs', nargs='+', type=int, choices=LEGS, default=list(LEGS), metavar='LEG',
                    help='legs the routine moves (default all six)')
    ap.add_argument('--phases', nargs='+', choices=PHASES, default=list(PHASES), metavar='PHASE',
                    help=f'phases of the routine to run (default all: {", ".join(PHASES)})')
    ap.add_argument('--robot', metavar='ROBOT.yaml', type=existing_file,
                    help='robot description (default: the packaged data/robot.yaml)')
    add_overlay_option(ap)
    add_no_progress_option(ap)
    return ap


def main(argv=None) -> int:
    ap = build_parser()
    args = ap.parse_args(argv)
    from hexapod_driver.bus import DynamixelBus
    from hexapod_driver.config import DriverConfig
    from hexapod_model.bus import BusError
    from hexapod_model.description import DescriptionError, load_robot
    from hexapod_sim.calibration.plan import CalibrationError, calibration_plan, run_calibration
    out = Path(args.out)
    try:
        robot = load_robot(args.robot, overlays=args.overlay)
        plan = calibration_plan(robot, legs=tuple(sorted(set(args.legs))), phases=tuple(args.phases),
                                speed_scale=args.speed_scale)
    except (DescriptionError, CalibrationError) as exc:
        ap.error(str(exc))
    bus = DynamixelBus(robot, DriverConfig(device=args.device))
    try:
        bus.start()                       # a bus that cannot start is the one line below
        print(f'stand calibration: {plan.duration_s:.1f} s on legs {", ".join(map(str, plan.legs))} through '
              f'{args.device}; the robot must hang free on its stand', file=sys.stderr, flush=True)
        rec = run_calibration(bus, plan, progress=args.progress, robot=robot)
    except (BusError, CalibrationError, OSError) as exc:
        print(f'{ap.prog}: error: {" ".join(str(exc).split())}', file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f'{ap.prog}: interrupted; no bag written', file=sys.stderr)
        return 130
    finally:
        bus.close()                       # torque off
    rec.write_bag(out)
    n_reads = sum(len(s) for s in rec.states.values())
    n_writes = len({float(t) for s in rec.commands.values() for t in s.t_s})
    print(f'wrote {out}: {rec.duration_s:.1f} s, {n_writes} goal writes, {n_reads} position reads; '
          f'next: ./hexapod discrepancy {out}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
