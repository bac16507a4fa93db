"""The compiled swing-down kernels of :mod:`hexapod_model.swing_model`: the rigid leg's substep, the
rollout of several legs (rigid legs three abreast, legs with gear backlash by
:mod:`hexapod_model.swing_backlash`) and CalcModel's fused prediction of all swinging legs. Pure numba.
"""
from __future__ import annotations

import math

import numpy as np

from hexapod_model.swing_backlash import _rollout_backlash
from hexapod_model.swing_common import (
    _FASTMATH,
    P_A2,
    P_B2,
    P_B3,
    P_BL2,
    P_BL3,
    P_DT,
    P_FC2,
    P_FC3,
    P_FS2,
    P_FS3,
    P_G,
    P_I1,
    P_I2,
    P_J2,
    P_J3,
    P_LC1,
    P_LC2,
    P_M1,
    P_M2,
    P_OFF2,
    P_OFF3,
    P_SUBSTEPS,
    V_STICK,
    _servo_torques,
    njit,
)


@njit(cache=True, fastmath=_FASTMATH, nogil=True, inline='always')
def _rotate(c, s, d):
    """(cos, sin) of an angle advanced by ``d`` from its (cos, sin): a rotation, with the Taylor
    series of cos/sin of ``d`` (exact to round-off for |d| < 0.01 rad; math.cos/sin beyond)."""
    if abs(d) < 0.01:
        d2 = d * d
        cd = 1.0 - d2 * (0.5 - d2 * (1.0 / 24.0 - d2 * (1.0 / 720.0)))
        sd = d * (1.0 - d2 * (1.0 / 6.0 - d2 * (1.0 / 120.0 - d2 * (1.0 / 5040.0))))
    else:
        cd = math.cos(d)
        sd = math.sin(d)
    return c * cd - s * sd, s * cd + c * sd


@njit(cache=True, fastmath=_FASTMATH, nogil=True, inline='always')
def _rotate_small(c, s, d):
    """:func:`_rotate` for |d| < 0.01 only (its Taylor branch, no branch: callers check |d| and redo
    larger increments with :func:`_rotate`)."""
    d2 = d * d
    cd = 1.0 - d2 * (0.5 - d2 * (1.0 / 24.0 - d2 * (1.0 / 720.0)))
    sd = d * (1.0 - d2 * (1.0 / 6.0 - d2 * (1.0 / 120.0 - d2 * (1.0 / 5040.0))))
    return c * cd - s * sd, s * cd + c * sd



@njit(cache=True, fastmath=_FASTMATH, nogil=True, inline='always')
def _rigid_constants(p):
    """Per-leg constants of :func:`_rigid_substep` (mass matrix, gravity, damping, friction, step)."""
    m1, lc1, i1 = p[P_M1], p[P_LC1], p[P_I1]
    m2, lc2, i2, a2, g = p[P_M2], p[P_LC2], p[P_I2], p[P_A2], p[P_G]
    h = p[P_DT] / int(p[P_SUBSTEPS])
    k22 = m2 * lc2 * lc2 + i2 + p[P_J3]
    return (m1 * lc1 * lc1 + i1 + m2 * (a2 * a2 + lc2 * lc2) + i2 + p[P_J2],   # D11 without the cos term
            m2 * lc2 * lc2 + i2, k22, m2 * a2 * lc2, g * (m1 * lc1 + m2 * a2), g * m2 * lc2,
            k22 + h * p[P_B3], 1.0 / (h * (k22 + h * p[P_B3])), h, p[P_B2], p[P_FC2], p[P_FC3], p[P_FS2], p[P_FS3])


@njit(cache=True, fastmath=_FASTMATH, nogil=True, inline='always')
def _rigid_substep(c, tau2, tau3, q2, q3, v2, v3, c2, s2, c3, s3):
    """One semi-implicit Euler substep of a leg without backlash (Eq. 14, damping implicit, Coulomb
    / break-away friction as velocity-level impulses by Gauss-Seidel). ``c``: :func:`_rigid_constants`;
    ``c2, s2, c3, s3``: cos/sin of the link angles psi, carried along by :func:`_rotate_small` (no
    trig call, no branch). Returns the new ``(q2, q3, v2, v3, c2, s2, c3, s3, d2, d3)`` with the
    position increments ``d``: where one is 0.01 rad or more the caller redoes its rotation with
    :func:`_rotate` (from the old cos/sin), so the result is :func:`_rotate`'s either way."""
    k11c, k12c, k22, kc, gm1, gm2, a22, inv_ha22, h, b2, fc2, fc3, fs2, fs3 = c
    d11 = k11c + 2.0 * kc * c3
    d12 = k12c + kc * c3
    hh = -kc * s3
    cor1 = hh * (2.0 * v2 * v3 + v3 * v3)
    cor2 = -hh * v2 * v2
    g2 = gm2 * (c2 * c3 - s2 * s3)           # cos(psi2 + psi3)
    g1 = gm1 * c2 + g2
    a11 = d11 + h * b2
    det = a11 * a22 - d12 * d12
    inv_det = 1.0 / det
    inv11 = a22 * inv_det
    inv22 = a11 * inv_det
    inv12 = -d12 * inv_det
    r1 = d11 * v2 + d12 * v3 + h * (tau2 - cor1 - g1)
    r2 = d12 * v2 + k22 * v3 + h * (tau3 - cor2 - g2)
    w2 = inv11 * r1 + inv12 * r2
    w3 = inv12 * r1 + inv22 * r2
    lim2 = fs2 if abs(v2) < V_STICK else fc2
    lim3 = fs3 if abs(v3) < V_STICK else fc3
    k2 = det * inv_ha22              # 1 / (h inv11), with a22 constant
    k3 = 1.0 / (h * inv22)
    f2 = 0.0
    f3 = 0.0
    for _pass in range(2):
        for _it in range(3):  # Gauss-Seidel on the two friction impulses
            u2 = w2 + h * (inv11 * f2 + inv12 * f3)
            n2 = min(max(f2 - u2 * k2, -lim2), lim2)
            u3 = w3 + h * (inv12 * n2 + inv22 * f3)
            n3 = min(max(f3 - u3 * k3, -lim3), lim3)
            if n2 == f2 and n3 == f3:   # a sweep that changes nothing repeats forever: stop (exact)
                break
            f2 = n2
            f3 = n3
        n2 = w2 + h * (inv11 * f2 + inv12 * f3)
        n3 = w3 + h * (inv12 * f2 + inv22 * f3)
        # A velocity that reverses within the step passed through rest: the break-away level holds it
        # there (a second pass with it), wherever in the step the zero fell.
        x2 = n2 * v2 < 0.0 and lim2 < fs2
        x3 = n3 * v3 < 0.0 and lim3 < fs3
        if not (x2 or x3):
            break
        if x2:
            lim2 = fs2
        if x3:
            lim3 = fs3
    v2 = n2
    v3 = n3
    if abs(v2) < V_STICK:
        v2 = 0.0
    if abs(v3) < V_STICK:
        v3 = 0.0
    d2 = h * v2
    d3 = h * v3
    c2n, s2n = _rotate_small(c2, s2, d2)
    c3n, s3n = _rotate_small(c3, s3, d3)
    return q2 + d2, q3 + d3, v2, v3, c2n, s2n, c3n, s3n, d2, d3


@njit(cache=True, fastmath=_FASTMATH, nogil=True)
def _rollout_rigid3(pa, pb, pc, q0a, q0b, q0c, v0a, v0b, v0c, ga, gb, gc, per, qa, qb, qc, va, vb, vc, ta, tb, tc):
    """Three legs without backlash stepped side by side (see :func:`_rollout_legs`).

    A leg's substep is one serial chain (tick -> torque -> velocity -> friction -> position), so one
    leg alone leaves the CPU waiting on latencies; three independent chains in one loop body
    overlap. Fewer than three legs: pass one leg twice (it writes the same values twice).
    ``q0*``/``v0*`` (2,) initial state; ``g*`` (r, 2) goal rows, each held for ``per`` periods (the
    last one to the end); ``q*``/``v*`` (n + 1, 2); ``t*`` (n, 2) for n periods.
    """
    ca, cb, cc = _rigid_constants(pa), _rigid_constants(pb), _rigid_constants(pc)
    n_sub = int(pa[P_SUBSTEPS])
    qa2, qa3, va2, va3 = q0a[0], q0a[1], v0a[0], v0a[1]
    qb2, qb3, vb2, vb3 = q0b[0], q0b[1], v0b[0], v0b[1]
    qc2, qc3, vc2, vc3 = q0c[0], q0c[1], v0c[0], v0c[1]
    ac2, as2, ac3, as3 = (math.cos(qa2 + pa[P_OFF2]), math.sin(qa2 + pa[P_OFF2]),
                          math.cos(qa3 + pa[P_OFF3]), math.sin(qa3 + pa[P_OFF3]))
    bc2, bs2, bc3, bs3 = (math.cos(qb2 + pb[P_OFF2]), math.sin(qb2 + pb[P_OFF2]),
                          math.cos(qb3 + pb[P_OFF3]), math.sin(qb3 + pb[P_OFF3]))
    cc2, cs2, cc3, cs3 = (math.cos(qc2 + pc[P_OFF2]), math.sin(qc2 + pc[P_OFF2]),
                          math.cos(qc3 + pc[P_OFF3]), math.sin(qc3 + pc[P_OFF3]))
    qa[0, 0], qa[0, 1], va[0, 0], va[0, 1] = qa2, qa3, va2, va3
    qb[0, 0], qb[0, 1], vb[0, 0], vb[0, 1] = qb2, qb3, vb2, vb3
    qc[0, 0], qc[0, 1], vc[0, 0], vc[0, 1] = qc2, qc3, vc2, vc3
    last = ga.shape[0] - 1
    row = 0
    held = 0
    for k in range(ta.shape[0]):
        if held == per:                      # the next goal row (k // per, counted), capped at the last
            held = 0
            row = min(row + 1, last)
        held += 1
        ta2, ta3 = _servo_torques(pa, ga[row, 0], ga[row, 1], qa2, qa3)
        tb2, tb3 = _servo_torques(pb, gb[row, 0], gb[row, 1], qb2, qb3)
        tc2, tc3 = _servo_torques(pc, gc[row, 0], gc[row, 1], qc2, qc3)
        for _ in range(n_sub):
            qa2, qa3, va2, va3, nac2, nas2, nac3, nas3, da2, da3 = _rigid_substep(
                ca, ta2, ta3, qa2, qa3, va2, va3, ac2, as2, ac3, as3)
            qb2, qb3, vb2, vb3, nbc2, nbs2, nbc3, nbs3, db2, db3 = _rigid_substep(
                cb, tb2, tb3, qb2, qb3, vb2, vb3, bc2, bs2, bc3, bs3)
            qc2, qc3, vc2, vc3, ncc2, ncs2, ncc3, ncs3, dc2, dc3 = _rigid_substep(
                cc, tc2, tc3, qc2, qc3, vc2, vc3, cc2, cs2, cc3, cs3)
            if max(max(abs(da2), abs(da3)), max(abs(db2), abs(db3)), max(abs(dc2), abs(dc3))) >= 0.01:
                nac2, nas2 = _rotate(ac2, as2, da2)    # a fast joint: the exact rotation (rare)
                nac3, nas3 = _rotate(ac3, as3, da3)
                nbc2, nbs2 = _rotate(bc2, bs2, db2)
                nbc3, nbs3 = _rotate(bc3, bs3, db3)
                ncc2, ncs2 = _rotate(cc2, cs2, dc2)
                ncc3, ncs3 = _rotate(cc3, cs3, dc3)
            ac2, as2, ac3, as3 = nac2, nas2, nac3, nas3
            bc2, bs2, bc3, bs3 = nbc2, nbs2, nbc3, nbs3
            cc2, cs2, cc3, cs3 = ncc2, ncs2, ncc3, ncs3
        ta[k, 0], ta[k, 1], tb[k, 0], tb[k, 1], tc[k, 0], tc[k, 1] = ta2, ta3, tb2, tb3, tc2, tc3
        qa[k + 1, 0], qa[k + 1, 1], va[k + 1, 0], va[k + 1, 1] = qa2, qa3, va2, va3
        qb[k + 1, 0], qb[k + 1, 1], vb[k + 1, 0], vb[k + 1, 1] = qb2, qb3, vb2, vb3
        qc[k + 1, 0], qc[k + 1, 1], vc[k + 1, 0], vc[k + 1, 1] = qc2, qc3, vc2, vc3



@njit(cache=True, nogil=True)
def _rollout_legs(params, q0, qd0, goals, per, out_q, out_qd, out_tau, gap0, out_gap, idx):
    """Simulate ``L`` legs over ``n = out_tau.shape[1]`` control periods; allocates nothing.

    ``params`` (L, N_PARAMS); ``q0``, ``qd0``, ``gap0`` (L, 2); ``goals`` (L, r, 2) integer goal ticks,
    row ``i`` in effect for periods ``[i per, (i + 1) per)`` and the last row to the end (``per`` = 1:
    one row per period); ``out_q[l, k]``/``out_qd[l, k]`` the state at the start of period k (L, n + 1, 2),
    ``out_tau`` (L, n, 2) the firmware torque held over period k, ``out_gap`` the backlash gap
    ``q_motor - q_link`` (zero without backlash); ``idx`` (L,) int64 scratch. Legs with backlash
    run one by one (:func:`_rollout_backlash`), the others in groups of three sharing a substep
    count (:func:`_rollout_rigid3`).
    """
    n_rigid = 0
    for l in range(params.shape[0]):
        p = params[l]
        if p[P_BL2] > 0.0 or p[P_BL3] > 0.0:
            _rollout_backlash(p, q0[l], qd0[l], goals[l], per, out_q[l], out_qd[l], out_tau[l], gap0[l], out_gap[l])
        else:
            out_gap[l, :, :] = 0.0
            idx[n_rigid] = l
            n_rigid += 1
    start = 0
    while start < n_rigid:
        a = idx[start]
        b = a
        c = a
        if start + 1 < n_rigid and params[idx[start + 1], P_SUBSTEPS] == params[a, P_SUBSTEPS]:
            b = idx[start + 1]
            c = b
            if start + 2 < n_rigid and params[idx[start + 2], P_SUBSTEPS] == params[a, P_SUBSTEPS]:
                c = idx[start + 2]
        start += 1 + (b != a) + (c != b)
        _rollout_rigid3(params[a], params[b], params[c], q0[a], q0[b], q0[c], qd0[a], qd0[b], qd0[c],
                        goals[a], goals[b], goals[c], per, out_q[a], out_q[b], out_q[c],
                        out_qd[a], out_qd[b], out_qd[c], out_tau[a], out_tau[b], out_tau[c])



@njit(cache=True, nogil=True)
def _eq15_goal(init_tick, fin_tick, k, n_interp, approach_from, approach_rate):
    """Integer goal of Algorithm 1's step ``k``: ``rint(theta_init + frac (theta_fin - theta_init))`` with
    ``frac`` of :func:`goal_fraction` (Eq. 15, or its approach profile), in the operations of
    :func:`interpolated_goals` (strict float math, so the model's goals are the ones the controller writes)."""
    u = (k + 1.0) / n_interp
    if approach_rate < 1.0 and u > approach_from:
        u = approach_from + approach_rate * (u - approach_from)
    frac = min(u, 1.0)
    return np.rint(init_tick + frac * (fin_tick - init_tick))


@njit(cache=True, nogil=True, inline='always')
def _angle_ticks(q0, q_fin, center, rad_per_tick, ticks, direction):
    """The initial and final angles (``q0``, ``q_fin``: (L, 2) rad) as continuous ticks into ``ticks``
    (2, L, 2) (the operations of :func:`hexapod_model.servo.theta_to_tick`) and the sign of each
    leg's femur motion into ``direction`` (L,). Returns False, and writes nothing, when an angle is
    not finite."""
    n_legs = q0.shape[0]
    for l in range(n_legs):
        for j in range(2):
            if not (math.isfinite(q0[l, j]) and math.isfinite(q_fin[l, j])):
                return False
    init_t = ticks[0]
    fin_t = ticks[1]
    for l in range(n_legs):
        for j in range(2):
            init_t[l, j] = center + q0[l, j] / rad_per_tick
            fin_t[l, j] = center + q_fin[l, j] / rad_per_tick
        direction[l] = 1.0 if fin_t[l, 0] >= init_t[l, 0] else -1.0
    return True


@njit(cache=True, nogil=True, inline='always')
def _goals_per_step(init_t, fin_t, n_interp, approach_from, approach_rate, goal_buf):
    """The Eq. 15 goals of every leg, one row per step: ``goal_buf`` (L, K, 2)."""
    for l in range(goal_buf.shape[0]):
        for k in range(goal_buf.shape[1]):
            goal_buf[l, k, 0] = _eq15_goal(init_t[l, 0], fin_t[l, 0], k, n_interp, approach_from[l], approach_rate)
            goal_buf[l, k, 1] = _eq15_goal(init_t[l, 1], fin_t[l, 1], k, n_interp, approach_from[l], approach_rate)


@njit(cache=True, nogil=True, inline='always')
def _goals_per_period(init_t, fin_t, n_interp, approach_from, approach_rate, n_steps, t_con, dt, goal_buf):
    """The Eq. 15 goal of every leg in effect at each servo period: ``goal_buf`` (L, n, 2), step
    ``k = floor(t / t_con)`` (as :func:`hexapod_model.swing_model.goals_per_period`), capped at the last."""
    for l in range(goal_buf.shape[0]):
        k_prev = -1
        g2 = 0.0
        g3 = 0.0
        for j in range(goal_buf.shape[1]):
            # the step whose goal is in effect: floor(j dt / t_con) (as goals_per_period), capped
            kk = min(int(math.floor(j * dt / t_con + 1e-9)), n_steps - 1)
            if kk != k_prev:
                g2 = _eq15_goal(init_t[l, 0], fin_t[l, 0], kk, n_interp, approach_from[l], approach_rate)
                g3 = _eq15_goal(init_t[l, 1], fin_t[l, 1], kk, n_interp, approach_from[l], approach_rate)
                k_prev = kk
            goal_buf[l, j, 0] = g2
            goal_buf[l, j, 1] = g3


@njit(cache=True, nogil=True, inline='always')
def _femur_at(q, last, dt, x):
    """The femur angle of ``q`` ((last + 1, 2) on the grid ``j dt``) at time ``x >= 0``: linear
    interpolation between servo periods, as ``np.interp``, the last row from its time on."""
    if x >= last * dt:
        return q[last, 0]
    j = int(x / dt)
    while j > 0 and j * dt > x:
        j -= 1
    while j + 1 < last and (j + 1) * dt <= x:
        j += 1
    xj = j * dt
    if x == xj:
        return q[j, 0]
    return (q[j + 1, 0] - q[j, 0]) / ((j + 1) * dt - xj) * (x - xj) + q[j, 0]


@njit(cache=True, nogil=True, inline='always')
def _sample_reads(out_q, ticks, direction, n_interp, approach_from, approach_rate, t_con, t_com, read_delay, dt,
                  center, rad_per_tick, epsilon, out_t_read, out_des, out_est, out_err, out_thr):
    """Per step ``k`` and leg slot ``l``: the read instant ``k t_con + l t_com``, the goal, the
    predicted tick at the (delayed) sample instant (:func:`_femur_at`), the lag in the direction of
    motion and the Eq. 17 threshold."""
    init_t = ticks[0]
    fin_t = ticks[1]
    last = out_q.shape[1] - 1   # out_q has n_periods + 1 rows on the grid j dt
    for l in range(out_q.shape[0]):
        for k in range(out_des.shape[0]):
            t = k * t_con + l * t_com
            out_t_read[k, l] = t
            x = t - read_delay[l]
            if x < 0.0:
                x = 0.0
            th = _femur_at(out_q[l], last, dt, x)
            des = _eq15_goal(init_t[l, 0], fin_t[l, 0], k, n_interp, approach_from[l], approach_rate)
            est = center + th / rad_per_tick
            out_des[k, l] = des
            out_est[k, l] = est
            out_err[k, l] = direction[l] * (des - est)
            out_thr[k, l] = out_err[k, l] + epsilon


@njit(cache=True, nogil=True)
def _swing_down_kernel(params, q0, q_fin, qd0, gap0, n_interp, approach_from, approach_rate, n_reach, t_con, per_step,
                       t_com, read_delay, center,
                       rad_per_tick, epsilon, ticks, direction, reached, goal_buf, idx, out_t_read, out_des,
                       out_est, out_err, out_thr, out_q, out_qd, out_tau, out_gap):
    """CalcModel for all swinging legs in one call, allocating nothing (every array is the caller's).

    Returns False, and computes nothing, when an initial or final angle (``q0``, ``q_fin``: (L, 2)
    rad) is not finite. Otherwise per leg slot ``l``: the initial and final angles as ticks and the
    direction of motion (:func:`_angle_ticks`); the Eq. 15 goals (with the approach profile
    ``approach_from[l]``, ``approach_rate``: :func:`hexapod_model.swing_model.goal_fraction`) into
    ``goal_buf``: when ``t_con`` is ``per_step`` whole servo periods, one row per step (L, K, 2),
    each held for ``per_step`` periods; otherwise (``per_step`` = 0) the goal in effect at each servo
    period (L, n, 2); the legs simulated together by :func:`_rollout_legs` over the n periods of
    ``out_tau`` (``idx`` its (L,) scratch); then the reads of every step (:func:`_sample_reads`);
    ``reached`` (K,) whether step ``k``'s goal is theta_fin (``k + 1 >= n_reach``, the number of
    interpolation steps).
    """
    if not _angle_ticks(q0, q_fin, center, rad_per_tick, ticks, direction):
        return False
    n_steps = out_des.shape[0]
    for k in range(n_steps):
        reached[k] = k + 1 >= n_reach
    dt = params[0, P_DT]
    if per_step > 0:
        _goals_per_step(ticks[0], ticks[1], n_interp, approach_from, approach_rate, goal_buf)
        _rollout_legs(params, q0, qd0, goal_buf, per_step, out_q, out_qd, out_tau, gap0, out_gap, idx)
    else:
        _goals_per_period(ticks[0], ticks[1], n_interp, approach_from, approach_rate, n_steps, t_con, dt, goal_buf)
        _rollout_legs(params, q0, qd0, goal_buf, 1, out_q, out_qd, out_tau, gap0, out_gap, idx)
    _sample_reads(out_q, ticks, direction, n_interp, approach_from, approach_rate, t_con, t_com, read_delay, dt,
                  center, rad_per_tick, epsilon, out_t_read, out_des, out_est, out_err, out_thr)
    return True
