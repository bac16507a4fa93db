"""A swinging leg's motion in the air, and a leg that meets an obstacle on its way. Pure numpy.

During the swing-up and swing-forward a leg in the air follows its goals as the leg model of the
swing-down (:class:`hexapod_model.swing_model.LegModel`, Eq. 11-14) predicts when it is run from rest
at the goals the swing began at, over the goals written since (held between writes, one per servo
control period). :func:`in_air_rollouts` runs it; the controller takes from it the legs' speeds at the
swing-down start (``start_in_motion``) and, with :func:`obstructed`, the legs whose femur or tibia
read is further from it than a free swing can be: a foot held back by the side of a block.

Measured (the simulated robot walking 2 m straight ahead, correction on, reflex off, the largest distance
of a femur or tibia read from the model over each swing-up and swing-forward): on flat ground at most
2.1 / 3.1 / 2.1 degrees (tripod / tetrapod / pentapod, about 100 swings each); over the blocks (tripod,
seed 9) 90 % of swings within 2.3 degrees, brushes of a block edge 5-11 degrees, and the foot held by
a block's side 18-33 degrees (the tibia), on which the servos pushed the trunk up 1.5 cm off two of its
three stance feet.
"""
from __future__ import annotations

import numpy as np

from hexapod_model.servo import ServoParams, theta_to_tick
from hexapod_model.swing_model import LegModel, Rollout

# (bus time [s], (L, 2) femur and tibia goals [rad] of the swinging legs) per goal write since the swing began
GoalLog = list[tuple[float, np.ndarray]]


def in_air_rollouts(models: dict[int, LegModel], legs, log: GoalLog, servo: ServoParams,
                    t_end_s: float) -> list[Rollout] | None:
    """Each leg of ``legs`` (the log's order) in the air from rest at its goals when the swing began, driven
    by the goals written since up to ``t_end_s``; the rollouts start at ``log[0][0]``. None with less than
    one control period of log."""
    dt = servo.control_period_s
    if not log or t_end_s - log[0][0] < dt:
        return None
    ts = np.array([t for t, _ in log])
    grid = log[0][0] + dt * np.arange(int((t_end_s - log[0][0]) / dt + 1e-9))
    held = np.searchsorted(ts, grid + 1e-9, side='right') - 1
    ticks = np.rint(theta_to_tick(np.stack([v for _, v in log])[held], servo))   # (n, L, 2)
    return [models[leg].rollout(log[0][1][slot], [0.0, 0.0], ticks[:, slot]) for slot, leg in enumerate(legs)]


def obstructed(rollouts: list[Rollout], legs, t0_s: float, reads: dict[int, list[tuple[float, float]]],
               limit_rad: float) -> dict[int, float]:
    """The legs whose femur or tibia read lies more than ``limit_rad`` from their rollout (started at
    ``t0_s``), with that distance [rad]. ``reads``: per leg, the latest (theta [rad], sample time [s]) of
    its femur and tibia, or None for a joint not read since the swing began."""
    out = {}
    for slot, leg in enumerate(legs):
        ro = rollouts[slot]
        worst = 0.0
        for k, read in enumerate(reads.get(leg, ())):
            if read is None or read[1] < t0_s:
                continue
            i = min(len(ro.q_rad) - 1, int(round((read[1] - t0_s) / ro.dt_s)))
            worst = max(worst, abs(read[0] - float(ro.q_rad[i, k])))
        if worst > limit_rad:
            out[leg] = worst
    return out
