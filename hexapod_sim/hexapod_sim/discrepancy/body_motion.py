"""The body's motion under a walk's swings, from the recording's ``/imu``.

The free-leg model of :mod:`.simulate` hangs each leg from a body at rest. In a walk the body moves
under the swinging legs: the overlapped gait cycle levels and shifts it while the next group swings up
and forward, and touchdowns rock it on its compliant stance legs. In the trunk's frame a leg then
feels, besides gravity, the fictitious forces of that frame: for a point at ``r`` from the IMU,
``-(a + alpha x r + omega x (omega x r))`` per unit mass (the Coriolis term of a leg's own motion is
left out). An IMU on the trunk measures the specific force ``f = R^T (a - g)`` and ``omega``, so
gravity minus the trunk's acceleration is ``-f``, and ``alpha`` is the derivative of ``omega``.

So the swings are replayed once more through the MuJoCo hexapod on a welded base (coupled three-joint
legs, the servo firmware), with gravity set every millisecond to ``-f`` and the rotational terms applied
as forces at every leg link's centre of mass, each leg restarted at every swing from the same recorded
state as the free-leg replay. The difference between that nominal replay and the free-leg model's
nominal replay, per read, is a correction added to every prediction
(:attr:`.simulate.Replay.correction`): the candidate effects still act through the fast free-leg model,
so a fit costs what it did; their interaction with the body's motion is left out.

Measured on clean sim walks of the default gait cycle: docs/discrepancy.md, "Which walks".
"""
from __future__ import annotations

import numpy as np

from hexapod_model.description import Robot
from hexapod_model.imu import ImuSeries
from hexapod_model.joints import LEG_JOINTS, Joint
from hexapod_model.servo import theta_to_tick
from hexapod_sim.discrepancy.recording import Recording
from hexapod_sim.discrepancy.simulate import Replay


def gravity_per_period(imu: ImuSeries, n_periods: int, dt: float) -> np.ndarray:
    """(n_periods, 3) gravity for a welded trunk, minus the body's acceleration, in its frame: ``-f`` of
    the IMU interpolated onto the firmware's grid (held at the ends)."""
    t = np.arange(n_periods) * dt
    return np.column_stack([np.interp(t, imu.t_s, -imu.accel[:, c]) for c in range(3)])


ALPHA_SMOOTH_S = 0.01      # angular acceleration: derivative of omega over +-10 ms (the IMU samples at 400 Hz)


def rotation_per_period(imu: ImuSeries, n_periods: int, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """(omega, alpha), each (n_periods, 3) in the body frame: the IMU's angular velocity interpolated onto
    the firmware's grid, and its central difference over ``ALPHA_SMOOTH_S``."""
    t = np.arange(n_periods) * dt
    w = np.column_stack([np.interp(t, imu.t_s, imu.gyro[:, c]) for c in range(3)])
    h = ALPHA_SMOOTH_S
    a = np.column_stack([(np.interp(t + h, imu.t_s, imu.gyro[:, c]) - np.interp(t - h, imu.t_s, imu.gyro[:, c]))
                         / (2 * h) for c in range(3)])
    return w, a


def body_motion_correction(replay: Replay, rec: Recording, robot: Robot) -> dict[Joint, np.ndarray]:
    """Per analysed joint, at each of its analysed reads: the MuJoCo replay with the body's measured motion
    minus the free-leg model's nominal prediction [ticks]. Needs ``rec.imu``."""
    from hexapod_sim.physics.plant import HexapodSim
    if rec.imu is None:
        raise ValueError('body_motion_correction needs a recording with /imu')
    dt = replay.dt
    n = replay.n_periods
    sim = HexapodSim(robot, fixed_base=True, imu_rate_hz=0.0)
    sim.reset()
    m, d = sim.model, sim.data
    trunk = m.body('trunk').id
    rot = d.xmat[trunk].reshape(3, 3).copy()               # welded: body frame -> world, constant
    gravity = gravity_per_period(rec.imu, n, dt) @ rot.T
    omega, alpha = rotation_per_period(rec.imu, n, dt)
    omega, alpha = omega @ rot.T, alpha @ rot.T
    links = np.array([b for b in range(m.nbody) if m.body_rootid[b] == m.body_rootid[trunk] and b != trunk
                      and m.body_mass[b] > 0 and m.body_parentid[b] != 0])
    mass = m.body_mass[links][:, None]
    writes = rec.writes_by_tick(dt)
    starts: dict[int, list[tuple[int, int]]] = {}
    for leg in replay.legs:
        for i, (ka, _) in enumerate(replay.segments[leg]):
            starts.setdefault(ka, []).append((leg, i))
    cols = {j: c for c, j in enumerate(replay.joints)}
    idx = [sim.joint_position_index(str(j)) for j in replay.joints]
    grid = np.empty((n, len(cols)))
    qpos = sim.data.qpos
    for k in range(n - 1):
        sim.set_gravity(gravity[k])
        r = d.xipos[links] - d.xpos[trunk]
        w = omega[k]
        d.xfrc_applied[links, :3] = -mass * (np.cross(alpha[k], r) + np.cross(w, np.cross(w, r)))
        for leg, i in starts.get(k, ()):
            names = [str(j) for j in LEG_JOINTS[leg]]
            sim.set_joint_state(dict(zip(names, replay.q0[(leg, i)].tolist())),
                                dict(zip(names, replay.dq0[(leg, i)].tolist())))
        grid[k] = qpos[idx]
        goals = writes.get(k)
        if goals:
            sim.sync_write(goals)
        sim.step(dt)
    grid[n - 1] = qpos[idx]
    out = {}
    held, replay.correction = replay.correction, None       # the free-leg model's own prediction
    try:
        free = replay.predict(robot)
    finally:
        replay.correction = held
    for j in replay.joints:
        r = replay.reads[j]
        x = np.clip(r.t_s / dt, 0.0, n - 1.0)
        i0 = np.minimum(np.floor(x).astype(np.int64), n - 2)
        f = x - i0
        th = grid[i0, cols[j]] * (1.0 - f) + grid[i0 + 1, cols[j]] * f
        out[j] = theta_to_tick(th, robot.servo) - free[j]
    return out


__all__ = ['body_motion_correction', 'gravity_per_period']
