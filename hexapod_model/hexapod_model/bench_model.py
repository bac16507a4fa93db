"""Benchmark: time to predict a full 2 s swing-down at 1 kHz for three legs (not a test).

Target: median at most 0.3 ms on the project's 2-core machine (at most 1 ms lets a prediction fit
inside one bus read). Run: ``./hexapod bench``.
"""
from __future__ import annotations

import time

import numpy as np

from hexapod_model.description import load_robot
from hexapod_model.swing_model import LegModel, predict_swing_down

TARGET_MS = 0.3


def main(argv=None) -> None:
    from hexapod_model.cli_common import fail, make_parser, positive_float, positive_int
    ap = make_parser('bench_model', __doc__.splitlines()[0])
    ap.add_argument('--repeats', type=positive_int, default=500, help='timed predictions')
    ap.add_argument('--t-des', type=positive_float, default=2.0, help='swing-down duration [s]')
    args = ap.parse_args(argv)
    robot = load_robot()
    legs = [1, 6, 3]
    init = np.array([[0.45, 0.1]] * 3)
    fin = np.array([[-0.15, -0.05]] * 3)
    t_com = robot.bus.t_com_s
    n_steps = int(round(args.t_des / (len(legs) * t_com)))      # exactly t_des of control steps
    if n_steps < 1:
        fail(ap, f'--t-des {args.t_des:g} is shorter than one control period ({len(legs) * t_com * 1e3:g} ms)')
    models = {leg: LegModel(robot, leg) for leg in legs}
    t0 = time.perf_counter()
    predict_swing_down(robot, legs, init, fin, args.t_des, t_com, n_steps=n_steps, models=models)
    first = time.perf_counter() - t0
    times = []
    for _ in range(args.repeats):
        t0 = time.perf_counter()
        predict_swing_down(robot, legs, init, fin, args.t_des, t_com, n_steps=n_steps, models=models)
        times.append(time.perf_counter() - t0)
    t = np.array(times) * 1e3
    periods = int(args.t_des / robot.servo.control_period_s)
    print(f'swing-down prediction: {len(legs)} legs x {periods} servo periods (1 kHz), '
          f'{n_steps} control steps of t_con={len(legs) * t_com * 1e3:.0f} ms')
    print(f'first call (includes JIT load/compile): {first * 1e3:.1f} ms')
    print(f'median {np.median(t):.3f} ms   p90 {np.percentile(t, 90):.3f} ms   min {t.min():.3f} ms   '
          f'({args.repeats} repeats)   target <= {TARGET_MS:g} ms: {"MET" if np.median(t) <= TARGET_MS else "MISSED"}')


if __name__ == '__main__':
    main()
