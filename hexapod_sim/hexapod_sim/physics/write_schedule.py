"""A recorded sequence of goal writes replayed through :class:`~.plant.HexapodSim` in one compiled loop.

A whole-walk replay (:mod:`hexapod_sim.discrepancy.whole_walk`) writes every recorded sync write at the
physics step it acts on and steps the sim to the next one: thousands of writes per replay, each a
:meth:`~.plant.HexapodSim.sync_write` and a :meth:`~.plant.HexapodSim.step` from Python. A
:class:`WriteSchedule` holds those writes as flat arrays, and :func:`replay_writes` applies them inside
the compiled loop (:func:`~.firmware.write_goals` at each write's step, :func:`~.firmware.run` between
writes), returning to Python only where the loop itself does: to empty the power window or the sensor
buffer. It is the same computation as the Python loop, in the same order (a test checks it bit for bit);
a sim whose goals act later than they are written (a goal latency) or whose writes take time is replayed
through the Python loop instead (:func:`can_replay`).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

from hexapod_model.description import ALL_JOINTS
from hexapod_model.servo import ERR_ANGLE_LIMIT
from hexapod_sim.physics import firmware
from hexapod_sim.physics.plant_tables import POWER_WINDOW


@dataclass(frozen=True)
class WriteSchedule:
    """Goal writes in step order: write ``w`` sets joints ``idx[start[w]:start[w + 1]]`` (indices into
    ``ALL_JOINTS``) to ``angle_rad[...]`` at physics step ``step[w]``."""

    step: np.ndarray          # (n,) int64, non-decreasing
    start: np.ndarray         # (n + 1,) int64
    idx: np.ndarray           # int64
    angle_rad: np.ndarray     # float64

    @classmethod
    def of(cls, writes) -> 'WriteSchedule | None':
        """From ``writes`` as (step, {joint name: angle [rad]}) in step order; None when a name is not a
        joint or an angle is not finite (the Python loop then reports it as the sim does)."""
        index = {name: i for i, name in enumerate(ALL_JOINTS)}
        steps, starts, idx, vals = [], [0], [], []
        for k, goals in writes:
            for name, v in goals.items():
                if name not in index:
                    return None
                idx.append(index[name])
                vals.append(v)
            steps.append(k)
            starts.append(len(idx))
        out = cls(np.asarray(steps, dtype=np.int64), np.asarray(starts, dtype=np.int64),
                  np.asarray(idx, dtype=np.int64), np.asarray(vals, dtype=np.float64))
        return out if np.all(np.isfinite(out.angle_rad)) else None


@njit(cache=True)
def _run_writes(target, n_writes, w_step, w_start, w_idx, w_val, w_next, lim_lo, lim_hi, scale, base, angle_bit,
                error_bits, goal,
                m_ptr, d_ptr, st, spm, max_tick, v_stick, imu_adr, qpos, qvel, qacc, ctrl, dof_frictionloss,
                jint, jflt, table, stick_int, stick_flt, win_tau, win_omega, tau_out, sens_buf, sens_step, hist,
                qfrc_applied, dint, dflt, supply):
    """Writes due at the current step (before stepping), then :func:`firmware.run` to the next write or
    ``target``, until ``target`` or until the power window or the sensor buffer is full after a run (the
    caller empties it and calls again); -> the next write's index."""
    n_win = win_tau.shape[0]
    n_sens = sens_buf.shape[0]
    while st[firmware.ST_STEP] < target:
        while w_next < n_writes and w_step[w_next] <= st[firmware.ST_STEP]:
            a, b = w_start[w_next], w_start[w_next + 1]
            firmware.write_goals(w_idx[a:b], w_val[a:b], lim_lo, lim_hi, scale, base, max_tick, angle_bit,
                                 error_bits, goal, jint)
            w_next += 1
        stop = target
        if w_next < n_writes and w_step[w_next] < stop:
            stop = w_step[w_next]
        firmware.run(stop, m_ptr, d_ptr, st, spm, max_tick, v_stick, imu_adr, qpos, qvel, qacc, ctrl,
                     dof_frictionloss, jint, jflt, table, stick_int, stick_flt, win_tau, win_omega, tau_out,
                     sens_buf, sens_step, hist, qfrc_applied, dint, dflt, supply)
        if st[firmware.ST_WIN_N] == n_win or (n_sens > 0 and st[firmware.ST_SENS_N] == n_sens):
            break
    return w_next


def can_replay(sim) -> bool:
    """Whether :func:`replay_writes` replays ``sim`` (a :class:`~.plant.HexapodSim`) as its Python loop
    would: goals act when written (no goal latency pending or configured) and a write takes no time."""
    return sim.writes_act_when_written


def replay_writes(sim, schedule: WriteSchedule, target_step: int, next_write: int) -> int:
    """Advance ``sim`` to physics step ``target_step``, applying the writes of ``schedule`` from index
    ``next_write`` at their steps (those at ``target_step`` itself are left for the next call, as
    stepping there and writing next does); -> the next write's index. Needs :func:`can_replay`."""
    st = sim._st
    start = next_write
    while st[firmware.ST_STEP] < target_step:
        next_write = _run_writes(target_step, len(schedule.step), schedule.step, schedule.start, schedule.idx,
                                 schedule.angle_rad, next_write, sim._lim_lo, sim._lim_hi, sim._tick_scale,
                                 sim._tick_base, ERR_ANGLE_LIMIT, sim._error_bits, sim._goal, *sim._loop_args)
        if st[firmware.ST_WIN_N] == POWER_WINDOW:
            sim._flush_power()
        if sim._sens_buf.shape[0] and st[firmware.ST_SENS_N] == sim._sens_buf.shape[0]:
            sim._drain_sensors()
    sim.bus_stats['writes'] += next_write - start
    return next_write


__all__ = ['WriteSchedule', 'can_replay', 'replay_writes']
