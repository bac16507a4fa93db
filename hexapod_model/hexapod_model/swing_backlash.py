"""The swing-down kernel of a leg with gear backlash (:mod:`hexapod_model.swing_model`). Pure numba.

A joint with play splits into the motor side (reflected rotor inertia ``J R^2``, damping,
Coulomb/break-away friction, driven by the firmware torque) and the link side (the leg, no friction
of its own), coupled by a dead zone of total width ``w``: the gap ``delta = q_motor - q_link`` stays
within ``[-w/2, w/2]``. The potentiometer, and so the firmware, sees the link. Contact is inelastic
and enforced at velocity level (speculative: the relative velocity may close the remaining gap
within the step, no more). Friction and contact impulses are solved together by projected
Gauss-Seidel. A joint of the leg without play is stepped as in the rigid kernel, its motor side
mirroring the link.
"""
from __future__ import annotations

import math

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


@njit(cache=True, fastmath=_FASTMATH, nogil=True)
def _play_contact(ch, cl, f, um, am, u, inv_self, inv_cross, t_other, lo, hi, h):
    """One projected Gauss-Seidel pass over the two contact sides of one joint's backlash play
    (see :func:`_backlash_substep`): the upper-side torque ``ch >= 0``, then the lower-side ``cl <=
    0``, each so that the motor-link relative velocity does not close the gap beyond ``hi`` / ``lo``
    within the step. ``u``, ``inv_self``, ``inv_cross`` and ``t_other`` give this joint's link
    velocity from the contact torques; ``f``, ``um``, ``am`` its motor side. Returns ``(ch, cl)``."""
    keff = h * (1.0 / am + inv_self)
    nm = um + h * (f - ch - cl) / am
    nv = u + h * (inv_self * (ch + cl) + inv_cross * t_other)
    ch = max(ch + (nm - nv - hi) / keff, 0.0)
    nm = um + h * (f - ch - cl) / am
    nv = u + h * (inv_self * (ch + cl) + inv_cross * t_other)
    return ch, min(cl + (nm - nv - lo) / keff, 0.0)


@njit(cache=True, fastmath=_FASTMATH, nogil=True, inline='always')
def _link_step(p, h, tau2, tau3, q2, q3, v2, v3, r2, r3):
    """The link side's semi-implicit step before friction and contact impulses: the inverse of its
    effective mass matrix ``(inv11, inv12, inv22)`` and the link velocities ``(u2, u3)`` it gives.
    A rigid joint (``r2``/``r3``) carries its rotor inertia, damping and firmware torque."""
    m1, lc1, i1 = p[P_M1], p[P_LC1], p[P_I1]
    m2, lc2, i2, a2, g = p[P_M2], p[P_LC2], p[P_I2], p[P_A2], p[P_G]
    jl2 = p[P_J2] if r2 else 0.0
    jl3 = p[P_J3] if r3 else 0.0
    kc = m2 * a2 * lc2
    psi2 = q2 + p[P_OFF2]
    psi3 = q3 + p[P_OFF3]
    c3 = math.cos(psi3)
    s3 = math.sin(psi3)
    d11 = m1 * lc1 * lc1 + i1 + m2 * (a2 * a2 + lc2 * lc2) + i2 + 2.0 * kc * c3 + jl2
    d12 = m2 * lc2 * lc2 + i2 + kc * c3
    d22 = m2 * lc2 * lc2 + i2 + jl3
    hh = -kc * s3
    cor1 = hh * (2.0 * v2 * v3 + v3 * v3)
    cor2 = -hh * v2 * v2
    g2 = g * m2 * lc2 * math.cos(psi2 + psi3)
    g1 = g * (m1 * lc1 + m2 * a2) * math.cos(psi2) + g2
    a11 = d11 + (h * p[P_B2] if r2 else 0.0)
    a22 = d22 + (h * p[P_B3] if r3 else 0.0)
    det = a11 * a22 - d12 * d12
    inv11 = a22 / det
    inv22 = a11 / det
    inv12 = -d12 / det
    rr1 = d11 * v2 + d12 * v3 + h * ((tau2 if r2 else 0.0) - cor1 - g1)
    rr2 = d12 * v2 + d22 * v3 + h * ((tau3 if r3 else 0.0) - cor2 - g2)
    return inv11, inv12, inv22, inv11 * rr1 + inv12 * rr2, inv12 * rr1 + inv22 * rr2


@njit(cache=True, fastmath=_FASTMATH, nogil=True, inline='always')
def _motor_sides(p, h, r2, r3, tau2, tau3, v2, v3, m2s, m3s, w2m, w3m, q2, q3):
    """Both joints' motor sides before the impulses (only used with backlash): the effective inertias
    ``(am2, am3)`` and velocities ``(um2, um3)``, the friction limits ``(lim2, lim3)`` (break-away
    at rest) and the bounds ``(lo2, hi2, lo3, hi3)`` of the motor-link relative velocity that keep
    each gap within its play."""
    bl2, bl3 = p[P_BL2], p[P_BL3]
    am2 = p[P_J2] + h * p[P_B2]
    am3 = p[P_J3] + h * p[P_B3]
    um2 = (p[P_J2] * w2m + h * tau2) / am2
    um3 = (p[P_J3] * w3m + h * tau3) / am3
    lim2 = p[P_FS2] if abs(w2m if not r2 else v2) < V_STICK else p[P_FC2]
    lim3 = p[P_FS3] if abs(w3m if not r3 else v3) < V_STICK else p[P_FC3]
    d2 = m2s - q2
    d3 = m3s - q3
    lo2 = (-0.5 * bl2 - d2) / h
    hi2 = (0.5 * bl2 - d2) / h
    lo3 = (-0.5 * bl3 - d3) / h
    hi3 = (0.5 * bl3 - d3) / h
    return (um2, um3, am2, am3), lim2, lim3, (lo2, hi2, lo3, hi3)


@njit(cache=True, fastmath=_FASTMATH, nogil=True, inline='always')
def _friction_step(rigid, f, nv, h, inv_self, um, am, ch, cl, lim):
    """One joint's friction torque after a Gauss-Seidel update: on the link if rigid (from its
    velocity ``nv``), on the motor otherwise (from the motor velocity of ``um``, ``am`` and the
    contact torques ``ch``, ``cl``); clipped to ``lim``."""
    if rigid:
        return min(max(f - nv / (h * inv_self), -lim), lim)
    nm = um + h * (f - ch - cl) / am
    return min(max(f - nm * am / h, -lim), lim)


@njit(cache=True, fastmath=_FASTMATH, nogil=True, inline='always')
def _impulse_sweep(r2, r3, imp, link, motor, lim2, lim3, gaps, h):
    """One Gauss-Seidel sweep over the friction and contact torques ``imp = (f2, f3, ch2, cl2, ch3,
    cl3)`` (``link``: :func:`_link_step`; ``motor``: ``(um2, um3, am2, am3)``; ``gaps``: ``(lo2,
    hi2, lo3, hi3)``). Returns the updated ``imp``."""
    f2, f3, ch2, cl2, ch3, cl3 = imp
    inv11, inv12, inv22, u2, u3 = link
    um2, um3, am2, am3 = motor
    lo2, hi2, lo3, hi3 = gaps
    # link-side generalized torques from the impulses
    t2 = (f2 if r2 else ch2 + cl2)
    t3 = (f3 if r3 else ch3 + cl3)
    nv2 = u2 + h * (inv11 * t2 + inv12 * t3)
    f2 = _friction_step(r2, f2, nv2, h, inv11, um2, am2, ch2, cl2, lim2)
    t2 = (f2 if r2 else ch2 + cl2)
    nv3 = u3 + h * (inv12 * t2 + inv22 * t3)
    f3 = _friction_step(r3, f3, nv3, h, inv22, um3, am3, ch3, cl3, lim3)
    t3 = (f3 if r3 else ch3 + cl3)
    if not r2:
        ch2, cl2 = _play_contact(ch2, cl2, f2, um2, am2, u2, inv11, inv12, t3, lo2, hi2, h)
        t2 = ch2 + cl2
    if not r3:
        ch3, cl3 = _play_contact(ch3, cl3, f3, um3, am3, u3, inv22, inv12, t2, lo3, hi3, h)
    return f2, f3, ch2, cl2, ch3, cl3


@njit(cache=True, fastmath=_FASTMATH, nogil=True, inline='always')
def _solve_impulses(p, r2, r3, v2, v3, w2m, w3m, link, motor, lim2, lim3, gaps, h):
    """The friction and contact torques of the substep by projected Gauss-Seidel, in up to two
    passes: a velocity (the motor's, for a joint with play) that reverses within the step passed
    through rest, so the second pass holds it with the break-away level. Returns the torques
    ``(f2, f3, ch2, cl2, ch3, cl3)`` and the link velocities ``(nv2, nv3)`` they give."""
    inv11, inv12, inv22, u2, u3 = link
    um2, um3, am2, am3 = motor
    f2 = 0.0   # friction torque (on the link if rigid, on the motor otherwise)
    f3 = 0.0
    ch2 = 0.0  # contact torque motor -> link, upper side (>= 0) and lower side (<= 0)
    cl2 = 0.0
    ch3 = 0.0
    cl3 = 0.0
    nv2 = u2
    nv3 = u3
    for _pass in range(2):
        for _it in range(6):
            f2, f3, ch2, cl2, ch3, cl3 = _impulse_sweep(r2, r3, (f2, f3, ch2, cl2, ch3, cl3), link, motor,
                                                        lim2, lim3, gaps, h)
        t2 = (f2 if r2 else ch2 + cl2)
        t3 = (f3 if r3 else ch3 + cl3)
        nv2 = u2 + h * (inv11 * t2 + inv12 * t3)
        nv3 = u3 + h * (inv12 * t2 + inv22 * t3)
        x2 = (nv2 * v2 if r2 else (um2 + h * (f2 - ch2 - cl2) / am2) * w2m) < 0.0 and lim2 < p[P_FS2]
        x3 = (nv3 * v3 if r3 else (um3 + h * (f3 - ch3 - cl3) / am3) * w3m) < 0.0 and lim3 < p[P_FS3]
        if not (x2 or x3):
            break
        if x2:
            lim2 = p[P_FS2]
        if x3:
            lim3 = p[P_FS3]
    return (f2, f3, ch2, cl2, ch3, cl3), nv2, nv3


@njit(cache=True, fastmath=_FASTMATH, nogil=True, inline='always')
def _joint_end(rigid, q, qm, nv, um, am, f, ch, cl, bl, h):
    """One joint at the end of the substep from its link velocity ``nv`` and impulses: velocities
    below :data:`V_STICK` are rest, a rigid joint's motor side mirrors its link, a motor side stays
    within the play despite round-off. Returns ``(q, qm, v, vm)``."""
    if rigid:
        if abs(nv) < V_STICK:
            nv = 0.0
        nm = nv
    else:
        nm = um + h * (f - ch - cl) / am
        if abs(nm) < V_STICK:
            nm = 0.0
    q += h * nv
    qm = q if rigid else qm + h * nm
    if not rigid:
        qm = min(max(qm, q - 0.5 * bl), q + 0.5 * bl)
    return q, qm, nv, nm


@njit(cache=True, fastmath=_FASTMATH, nogil=True)
def _backlash_substep(p, h, tau2, tau3, q2, q3, v2, v3, m2s, m3s, w2m, w3m):
    """One substep of the leg with gear backlash on one or both joints (see the module doc).

    Returns the new ``(q2, q3, v2, v3, m2s, m3s, w2m, w3m)`` (motor angle and velocity per joint;
    for a joint without backlash they mirror the link).
    """
    bl2, bl3 = p[P_BL2], p[P_BL3]
    r2 = bl2 <= 0.0          # rigid joint: rotor inertia, damping and friction act on the link
    r3 = bl3 <= 0.0
    link = _link_step(p, h, tau2, tau3, q2, q3, v2, v3, r2, r3)
    motor, lim2, lim3, gaps = _motor_sides(p, h, r2, r3, tau2, tau3, v2, v3, m2s, m3s, w2m, w3m, q2, q3)
    imp, nv2, nv3 = _solve_impulses(p, r2, r3, v2, v3, w2m, w3m, link, motor, lim2, lim3, gaps, h)
    um2, um3, am2, am3 = motor
    f2, f3, ch2, cl2, ch3, cl3 = imp
    q2, m2s, nv2, nm2 = _joint_end(r2, q2, m2s, nv2, um2, am2, f2, ch2, cl2, bl2, h)
    q3, m3s, nv3, nm3 = _joint_end(r3, q3, m3s, nv3, um3, am3, f3, ch3, cl3, bl3, h)
    return q2, q3, nv2, nv3, m2s, m3s, nm2, nm3


@njit(cache=True, fastmath=_FASTMATH, nogil=True)
def _rollout_backlash(p, q0, qd0, goals, per, out_q, out_qd, out_tau, gap0, out_gap):
    """One leg with gear backlash on one or both joints: :func:`_backlash_substep` per substep."""
    n_sub = int(p[P_SUBSTEPS])
    h = p[P_DT] / n_sub
    q2, q3 = q0[0], q0[1]
    v2, v3 = qd0[0], qd0[1]
    qm2 = q2 + (gap0[0] if p[P_BL2] > 0.0 else 0.0)
    qm3 = q3 + (gap0[1] if p[P_BL3] > 0.0 else 0.0)
    vm2, vm3 = v2, v3
    out_q[0, 0] = q2
    out_q[0, 1] = q3
    out_qd[0, 0] = v2
    out_qd[0, 1] = v3
    out_gap[0, 0] = qm2 - q2
    out_gap[0, 1] = qm3 - q3
    last = goals.shape[0] - 1
    row = 0
    held = 0
    for k in range(out_tau.shape[0]):
        if held == per:                      # as in swing_kernel._rollout_rigid3
            held = 0
            row = min(row + 1, last)
        held += 1
        tau2, tau3 = _servo_torques(p, goals[row, 0], goals[row, 1], q2, q3)
        out_tau[k, 0] = tau2
        out_tau[k, 1] = tau3
        for _ in range(n_sub):
            q2, q3, v2, v3, qm2, qm3, vm2, vm3 = _backlash_substep(
                p, h, tau2, tau3, q2, q3, v2, v3, qm2, qm3, vm2, vm3)
        out_q[k + 1, 0] = q2
        out_q[k + 1, 1] = q3
        out_qd[k + 1, 0] = v2
        out_qd[k + 1, 1] = v3
        out_gap[k + 1, 0] = qm2 - q2
        out_gap[k + 1, 1] = qm3 - q3
