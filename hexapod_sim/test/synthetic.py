"""Model-generated recordings: the calibration plan replayed through the model itself.

For tests and for developing without the MuJoCo sim: the plan's goal writes and sequential reads
are laid out on the bus timeline of :func:`hexapod_sim.calibration.plan.run_calibration` (one sync
write, then ``T_com`` per read), the model with the given effects is rolled out, and every read
reports the rounded tick, as a servo does. The concealed-data benchmark uses the MuJoCo sim
instead, so the tool never sees the generator's model there.
"""
from __future__ import annotations

import numpy as np

from hexapod_model.description import Robot
from hexapod_model.servo import quantize_tick, theta_to_tick, tick_to_theta
from hexapod_sim.calibration.plan import CalibrationPlan
from hexapod_sim.discrepancy.recording import Recording
from hexapod_sim.discrepancy.simulate import Replay


def bus_timeline(plan: CalibrationPlan, servo, t_com_s: float, t_write_s: float = 0.0):
    """Write and read stamps of :func:`run_calibration` on an ideal bus: (commands, reads) lists."""
    commands, reads = [], []
    t = 0.0
    last = None
    while t <= plan.duration_s:
        goals = plan.goals_dict(t)
        ticks = np.rint(theta_to_tick(np.array(list(goals.values())), servo))
        if last is None or np.any(ticks != last):
            commands.append((t, goals))
            last = ticks
            t += t_write_s
        for j in plan.read_joints(t):
            reads.append((t, j, goals[j]))
            t += t_com_s
    return commands, reads


def model_recording(robot: Robot, plan: CalibrationPlan, t_com_s: float | None = None) -> Recording:
    """Roll the model of ``robot`` (including its ``effects``) through ``plan``; quantized reads."""
    t_com = robot.bus.t_com_s if t_com_s is None else t_com_s
    commands, reads = bus_timeline(plan, robot.servo, t_com)
    draft = Recording.from_samples(commands, reads, source='model')
    rep = Replay(robot, draft)
    pred = rep.predict(robot)
    states = {}
    for j, r in rep.reads.items():
        states[j] = (r.t_s, tick_to_theta(quantize_tick(pred[j], robot.servo), robot.servo))
    rows = [(float(t), j, float(v)) for j, (ts, vs) in states.items() for t, v in zip(ts, vs)]
    return Recording.from_samples(commands, rows, source='model')
