"""Swing-down model of one leg with its AX-12A servos (paper Sec. 6-7, Eq. 11-17). Pure numpy/numba.

Dynamics (Eq. 11 with Eq. 12 reflected to the joint, i.e. Eq. 14 in joint units): the femur and
tibia of one leg form a two-link arm in the leg's vertical plane (coxa held, body level, no ground
contact)::

    (D(q) + J R^2) q'' + C(q, q') q' + B R^2 q' + F(q') + G(q) = tau_servo

``q = (theta_2, theta_3)`` (DH joint variables, ``psi = theta + theta_off`` is the link angle
above the horizontal for the femur). ``F`` is Coulomb friction ``tau_c R`` (optionally a larger
break-away torque at rest). ``tau_servo`` is the firmware law of :mod:`hexapod_model.servo`,
recomputed every control period (1 ms) from the integer present tick and held in between.

Time stepping: ``substeps`` semi-implicit Euler steps per control period (default 1: within 0.05
tick of a 50-substep reference over the Fig. 9 swings, see the tests), damping implicit,
friction as a velocity-level impulse (so a joint at rest sticks exactly until the drive torque
exceeds the break-away torque). A velocity that reverses within a step passed through rest there,
so the impulse of that step is bounded by the break-away torque too, wherever in the step the
zero fell (bounded by the Coulomb level, a reversal stuck only when it fell near the step's end).
The kernel is compiled with numba when available.

``predict_swing_down`` is the paper's ``CalcModel`` for L simultaneously swinging legs: it builds
the interpolated goal sequence of Eq. 15 (one new goal every ``t_con = L * T_com``), simulates the
legs and returns the predicted femur position at each sequential read of Algorithm 1 (leg ``l``
of step ``k`` is sampled at ``k t_con + l T_com``) with the Eq. 17 threshold.

Gear backlash (``backlash`` effect, used by the discrepancy tool): a joint with play splits into
the motor side (reflected rotor inertia, damping and friction, driven by the firmware torque) and
the link, coupled by a dead zone of total width ``w``; the potentiometer, and so the firmware,
sees the link. Without play the kernel runs exactly the rigid path above. :class:`CoxaModel`
reuses the same kernel for the coxa as a 1-DOF joint about the vertical axis (whole leg's inertia,
no gravity).

Sign convention for errors: the paper notes the comparison depends on the direction of motion
and on how the servo is mounted. All errors here are *lag in the direction of motion*,
``err = s (theta_des - theta)`` in ticks with ``s = sign(theta_fin - theta_init)`` of the femur,
so a leg held up by the ground shows a growing positive error.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from hexapod_model.description import JointEffects, Robot, ServoParams, joint_name
from hexapod_model.dictionary import T_DS, T_K, T_MU, T_PA, T_TS, joint_terms, supply_resistance_ohm
from hexapod_model.servo import firmware_torque_scalar

try:  # numba makes one 2 s prediction take well under a millisecond; the pure-Python path is exact too
    from numba import njit
except ImportError:  # pragma: no cover - numba is a pinned dependency
    def njit(*args, **kwargs):
        if args and callable(args[0]):
            return args[0]
        return lambda f: f

# Indices into the packed parameter vector of the kernel.
(P_M1, P_LC1, P_I1, P_M2, P_LC2, P_I2, P_A2, P_G, P_OFF2, P_OFF3, P_J2, P_J3, P_B2, P_B3,
 P_FC2, P_FC3, P_FS2, P_FS3, P_KP, P_TMAX2, P_TMAX3, P_MARG2, P_MARG3, P_RPT, P_CENTER, P_MAXTICK,
 P_CONTROL, P_SUBSTEPS, P_DT, P_BL2, P_BL3, P_PUNCH2, P_PUNCH3, N_PARAMS) = range(34)

# The servo law of the kernels is hexapod_model.servo's own scalar twin of firmware_torque_nm, compiled.
_firmware_torque = njit(cache=True, inline='always')(firmware_torque_scalar)

# fast-math without 'reassoc': with it LLVM reorders sums differently when it compiles a kernel in
# this process than in the object code it caches, so a freshly compiled kernel and the same kernel
# loaded from the numba cache differed in the last bits, and the same trial gave different JSON in a
# process pool (compiled) and on Ray (cached). Without it both agree bit for bit
# (test_a_freshly_compiled_kernel_and_the_cached_one_agree_bit_for_bit) at the same speed
# (bench_model median 0.229 ms with every flag, 0.223 ms without 'reassoc', side by side).
_FASTMATH = {'nnan', 'ninf', 'nsz', 'arcp', 'afn', 'contract'}

def joint_damping_nms_per_rad(servo: ServoParams, e: JointEffects, motor_scale: float = 1.0) -> float:
    """Viscous damping at one joint: the servo's reflected damping (times a motor-damping ratio and a weak
    motor's ``motor_scale``, :mod:`hexapod_model.dictionary`) plus any extra viscous damping of the joint;
    the one rule the model and the MuJoCo sim share."""
    return servo.reflected_damping_nms_per_rad * e.damping_ratio * motor_scale + e.extra_damping_nms_per_rad


V_STICK = 1e-7  # rad/s: below this a joint counts as at rest (break-away friction applies)
_NO_GAP = np.zeros(2)


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


@njit(cache=True, fastmath=_FASTMATH, nogil=True)
def _backlash_substep(p, h, tau2, tau3, q2, q3, v2, v3, m2s, m3s, w2m, w3m):
    """One substep of the leg with gear backlash on one or both joints (see :func:`_rollout_kernel`).

    A joint with backlash splits into the motor side (reflected rotor inertia ``J R^2``, damping,
    Coulomb/break-away friction, driven by the firmware torque) and the link side (the leg, no
    friction of its own), coupled by a dead zone of total width ``w``: the gap ``delta = q_motor -
    q_link`` stays within ``[-w/2, w/2]``. Contact is inelastic and enforced at velocity level
    (speculative: the relative velocity may close the remaining gap within the step, no more).
    Friction and contact impulses are solved together by projected Gauss-Seidel.
    Returns the new ``(q2, q3, v2, v3, m2s, m3s, w2m, w3m)`` (motor angle and velocity per joint;
    for a joint without backlash they mirror the link).
    """
    m1, lc1, i1 = p[P_M1], p[P_LC1], p[P_I1]
    m2, lc2, i2, a2, g = p[P_M2], p[P_LC2], p[P_I2], p[P_A2], p[P_G]
    bl2, bl3 = p[P_BL2], p[P_BL3]
    r2 = bl2 <= 0.0          # rigid joint: rotor inertia, damping and friction act on the link
    r3 = bl3 <= 0.0
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
    u2 = inv11 * rr1 + inv12 * rr2          # link velocities before friction/contact impulses
    u3 = inv12 * rr1 + inv22 * rr2
    # motor sides (only used for joints with backlash)
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
    f2 = 0.0   # friction torque (on the link if rigid, on the motor otherwise)
    f3 = 0.0
    ch2 = 0.0  # contact torque motor -> link, upper side (>= 0) and lower side (<= 0)
    cl2 = 0.0
    ch3 = 0.0
    cl3 = 0.0
    nv2 = u2
    nv3 = u3
    nm2 = um2
    nm3 = um3
    for _pass in range(2):
        for _it in range(6):
            # link-side generalized torques from the impulses
            t2 = (f2 if r2 else ch2 + cl2)
            t3 = (f3 if r3 else ch3 + cl3)
            nv2 = u2 + h * (inv11 * t2 + inv12 * t3)
            nv3 = u3 + h * (inv12 * t2 + inv22 * t3)
            if r2:
                f2 = min(max(f2 - nv2 / (h * inv11), -lim2), lim2)
            else:
                nm2 = um2 + h * (f2 - ch2 - cl2) / am2
                f2 = min(max(f2 - nm2 * am2 / h, -lim2), lim2)
            t2 = (f2 if r2 else ch2 + cl2)
            nv2 = u2 + h * (inv11 * t2 + inv12 * t3)
            nv3 = u3 + h * (inv12 * t2 + inv22 * t3)
            if r3:
                f3 = min(max(f3 - nv3 / (h * inv22), -lim3), lim3)
            else:
                nm3 = um3 + h * (f3 - ch3 - cl3) / am3
                f3 = min(max(f3 - nm3 * am3 / h, -lim3), lim3)
            t3 = (f3 if r3 else ch3 + cl3)
            nv2 = u2 + h * (inv11 * t2 + inv12 * t3)
            nv3 = u3 + h * (inv12 * t2 + inv22 * t3)
            if not r2:
                ch2, cl2 = _play_contact(ch2, cl2, f2, um2, am2, u2, inv11, inv12, t3, lo2, hi2, h)
                t2 = ch2 + cl2
                nv2 = u2 + h * (inv11 * t2 + inv12 * t3)
                nv3 = u3 + h * (inv12 * t2 + inv22 * t3)
            if not r3:
                ch3, cl3 = _play_contact(ch3, cl3, f3, um3, am3, u3, inv22, inv12, t2, lo3, hi3, h)
                t3 = ch3 + cl3
                nv2 = u2 + h * (inv11 * t2 + inv12 * t3)
                nv3 = u3 + h * (inv12 * t2 + inv22 * t3)
        t2 = (f2 if r2 else ch2 + cl2)
        t3 = (f3 if r3 else ch3 + cl3)
        nv2 = u2 + h * (inv11 * t2 + inv12 * t3)
        nv3 = u3 + h * (inv12 * t2 + inv22 * t3)
        # a velocity (the motor's, for a joint with play) that reverses within the step passed
        # through rest: the break-away level holds it there (a second pass with it)
        x2 = (nv2 * v2 if r2 else (um2 + h * (f2 - ch2 - cl2) / am2) * w2m) < 0.0 and lim2 < p[P_FS2]
        x3 = (nv3 * v3 if r3 else (um3 + h * (f3 - ch3 - cl3) / am3) * w3m) < 0.0 and lim3 < p[P_FS3]
        if not (x2 or x3):
            break
        if x2:
            lim2 = p[P_FS2]
        if x3:
            lim3 = p[P_FS3]
    if r2:
        if abs(nv2) < V_STICK:
            nv2 = 0.0
        nm2 = nv2
    else:
        nm2 = um2 + h * (f2 - ch2 - cl2) / am2
        if abs(nm2) < V_STICK:
            nm2 = 0.0
    if r3:
        if abs(nv3) < V_STICK:
            nv3 = 0.0
        nm3 = nv3
    else:
        nm3 = um3 + h * (f3 - ch3 - cl3) / am3
        if abs(nm3) < V_STICK:
            nm3 = 0.0
    q2 += h * nv2
    q3 += h * nv3
    m2s = q2 if r2 else m2s + h * nm2
    m3s = q3 if r3 else m3s + h * nm3
    # keep the gap inside the play despite round-off
    if not r2:
        m2s = min(max(m2s, q2 - 0.5 * bl2), q2 + 0.5 * bl2)
    if not r3:
        m3s = min(max(m3s, q3 - 0.5 * bl3), q3 + 0.5 * bl3)
    return q2, q3, nv2, nv3, m2s, m3s, nm2, nm3


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
def _servo_torques(p, goal2, goal3, q2, q3):
    """Both servos' firmware torques for the link angles: the present tick as the servo reports it
    (nearest integer, clipped) and the law of :func:`hexapod_model.servo.firmware_torque_scalar`."""
    if p[P_CONTROL] <= 0.5:
        return 0.0, 0.0
    pt2 = min(max(np.rint(p[P_CENTER] + q2 / p[P_RPT]), 0.0), p[P_MAXTICK])
    pt3 = min(max(np.rint(p[P_CENTER] + q3 / p[P_RPT]), 0.0), p[P_MAXTICK])
    return (_firmware_torque(goal2 - pt2, p[P_KP], p[P_TMAX2], p[P_MARG2], p[P_PUNCH2]),
            _firmware_torque(goal3 - pt3, p[P_KP], p[P_TMAX3], p[P_MARG3], p[P_PUNCH3]))


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
        if held == per:                      # as in _rollout_rigid3
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


@dataclass(frozen=True)
class Rollout:
    """Result of :meth:`LegModel.rollout`: ``q[k]``/``qd[k]`` at ``t = k dt``; ``tau[k]`` held on [k, k+1)."""

    dt_s: float
    q_rad: np.ndarray
    qd_rad_s: np.ndarray
    tau_nm: np.ndarray
    gap_rad: np.ndarray | None = None   # backlash gap q_motor - q_link per joint (zeros without backlash)

    def theta_at(self, t_s) -> np.ndarray:
        """Joint angles at arbitrary times (linear interpolation between control periods)."""
        t = np.asarray(t_s, dtype=float)
        grid = np.arange(len(self.q_rad)) * self.dt_s
        return np.stack([np.interp(t, grid, self.q_rad[:, j]) for j in range(2)], axis=-1)


class LegModel:
    """The two-link swing-down model of one leg, parameters taken from the robot description."""

    def __init__(self, robot: Robot, leg: int, substeps: int = 1, control: bool = True,
                 friction: bool = True, damping: bool = True, gravity: bool = True):
        self.robot = robot
        self.leg = leg
        s = robot.servo
        femur, tibia = robot.links['femur'], robot.links['tibia']
        a2, a3 = robot.dh['femur'].a_m, robot.dh['tibia'].a_m
        m2, lc2, i2 = tibia.mass_kg, tibia.com_from_joint_m, tibia.inertia_about_com_kgm2
        payload = robot.leg_payload_kg(leg)
        if payload > 0:  # point mass at the tibia tip: combine with the tibia link
            m_tot = m2 + payload
            lc_new = (m2 * lc2 + payload * a3) / m_tot
            i2 = i2 + m2 * (lc2 - lc_new) ** 2 + payload * (a3 - lc_new) ** 2
            m2, lc2 = m_tot, lc_new
        eff = [robot.joint_effects(joint_name(leg, r)) for r in ('femur', 'tibia')]
        self.terms = np.array([joint_terms(robot, joint_name(leg, r)) for r in ('femur', 'tibia')])
        p = np.zeros(N_PARAMS)
        p[P_M1], p[P_LC1], p[P_I1] = femur.mass_kg, femur.com_from_joint_m, femur.inertia_about_com_kgm2
        p[P_M2], p[P_LC2], p[P_I2], p[P_A2] = m2, lc2, i2, a2
        p[P_G] = robot.gravity_mps2 if gravity else 0.0
        p[P_OFF2], p[P_OFF3] = robot.dh['femur'].theta_off_rad, robot.dh['tibia'].theta_off_rad
        p[P_J2] = p[P_J3] = s.reflected_inertia_kgm2
        for j, e in enumerate(eff):
            fc = (s.reflected_coulomb_nm + e.extra_coulomb_nm) if friction else 0.0
            p[P_B2 + j] = joint_damping_nms_per_rad(s, e, self.terms[j, T_DS]) if damping else 0.0
            p[P_FC2 + j] = fc
            p[P_FS2 + j] = max(fc, e.static_friction_nm) if friction else 0.0
            p[P_TMAX2 + j] = s.stall_torque_nm if e.torque_max_nm is None else min(s.stall_torque_nm, e.torque_max_nm)
            p[P_MARG2 + j] = s.compliance_margin_ticks + e.deadband_margin_ticks
            p[P_PUNCH2 + j] = s.punch_nm + e.extra_punch_nm
            p[P_BL2 + j] = e.backlash_width_rad
        p[P_KP] = s.gain_nm_per_tick
        p[P_RPT], p[P_CENTER], p[P_MAXTICK] = s.rad_per_tick, s.center_tick, s.max_tick
        p[P_CONTROL] = 1.0 if control else 0.0
        p[P_SUBSTEPS] = int(substeps)
        p[P_DT] = s.control_period_s
        self.params = p
        self.dt_s = s.control_period_s
        # dictionary terms (hexapod_model.swing_terms): the supply as (R / V, 1 / (K R))
        self.supply = (supply_resistance_ohm(robot) / s.supply_voltage_v,
                       1.0 / (s.torque_constant_nm_per_a * s.gear_ratio))

    @property
    def has_terms(self) -> bool:
        """Whether a dictionary term acts on this model's joints (then :func:`swing_terms.rollout_terms` runs)."""
        t = self.terms
        return bool(self.supply[0] > 0 or np.any(t[:, [T_K, T_PA, T_MU]] != 0) or np.any(t[:, T_TS] != 1.0))

    def default_gap_rad(self, q0_rad) -> np.ndarray:
        """Initial backlash gap: the motor side rests against the link on the side that carries gravity."""
        widths = self.params[[P_BL2, P_BL3]]
        if not np.any(widths > 0):
            return np.zeros(2)
        return 0.5 * widths * np.sign(self.gravity_torque_nm(np.asarray(q0_rad, dtype=float)))

    def rollout(self, q0_rad, qd0_rad_s, goal_ticks, gap0_rad=None, i_ext=None) -> Rollout:
        """Simulate from ``q0`` with integer goal ticks per control period (array of shape (n, 2)).

        ``gap0_rad``: initial backlash gap ``q_motor - q_link`` per joint (default
        :meth:`default_gap_rad`); ignored for joints without backlash. ``i_ext``: per period, the
        stall current [A] of the robot's other servos (only a supply sag uses it).
        """
        goals = np.ascontiguousarray(goal_ticks, dtype=np.float64)
        if goals.ndim != 2 or goals.shape[1] != 2:
            raise ValueError(f'goal_ticks must have shape (n, 2), got {goals.shape}')
        q0 = np.asarray(q0_rad, dtype=np.float64).reshape(2)
        qd0 = np.asarray(qd0_rad_s, dtype=np.float64).reshape(2)
        if not (np.all(np.isfinite(goals)) and np.all(np.isfinite(q0)) and np.all(np.isfinite(qd0))):
            raise ValueError('swing-down model inputs contain NaN or infinity')
        p = self.params
        if self.has_terms:
            if p[P_BL2] > 0.0 or p[P_BL3] > 0.0:
                raise ValueError('dictionary terms on a leg with gear backlash are not modelled')
            from hexapod_model.swing_terms import rollout_terms
            q, qd, tau = rollout_terms(p, self.terms, self.supply, q0, qd0, goals, i_ext)
            return Rollout(self.dt_s, q, qd, tau, np.zeros_like(q))
        if gap0_rad is not None:
            gap0 = np.ascontiguousarray(gap0_rad, dtype=np.float64).reshape(2)
        elif p[P_BL2] > 0.0 or p[P_BL3] > 0.0:
            gap0 = self.default_gap_rad(q0)
        else:
            gap0 = _NO_GAP
        n = len(goals)
        q = np.empty((1, n + 1, 2))
        qd = np.empty((1, n + 1, 2))
        tau = np.empty((1, n, 2))
        gap = np.empty((1, n + 1, 2))
        _rollout_legs(p[None], q0[None], qd0[None], goals[None], 1, q, qd, tau, gap0[None], gap, np.empty(1, np.int64))
        return Rollout(self.dt_s, q[0], qd[0], tau[0], gap[0])

    # -- analysis helpers used by tests and tools
    def mass_matrix(self, q_rad) -> np.ndarray:
        p = self.params
        psi3 = q_rad[1] + p[P_OFF3]
        kc = p[P_M2] * p[P_A2] * p[P_LC2]
        d11 = p[P_M1] * p[P_LC1] ** 2 + p[P_I1] + p[P_M2] * (p[P_A2] ** 2 + p[P_LC2] ** 2) + p[P_I2] \
            + 2 * kc * math.cos(psi3) + p[P_J2]
        d12 = p[P_M2] * p[P_LC2] ** 2 + p[P_I2] + kc * math.cos(psi3)
        d22 = p[P_M2] * p[P_LC2] ** 2 + p[P_I2] + p[P_J3]
        return np.array([[d11, d12], [d12, d22]])

    def gravity_torque_nm(self, q_rad) -> np.ndarray:
        """G(q): joint torques needed to hold the leg against gravity."""
        p = self.params
        psi2, psi23 = q_rad[0] + p[P_OFF2], q_rad[0] + q_rad[1] + p[P_OFF2] + p[P_OFF3]
        g2 = p[P_G] * p[P_M2] * p[P_LC2] * math.cos(psi23)
        return np.array([p[P_G] * (p[P_M1] * p[P_LC1] + p[P_M2] * p[P_A2]) * math.cos(psi2) + g2, g2])

    def energy_j(self, q_rad, qd_rad_s) -> float:
        """Kinetic (links + reflected rotors) plus potential energy."""
        p = self.params
        qd = np.asarray(qd_rad_s)
        psi2, psi23 = q_rad[0] + p[P_OFF2], q_rad[0] + q_rad[1] + p[P_OFF2] + p[P_OFF3]
        pot = p[P_G] * ((p[P_M1] * p[P_LC1] + p[P_M2] * p[P_A2]) * math.sin(psi2)
                        + p[P_M2] * p[P_LC2] * math.sin(psi23))
        return float(0.5 * qd @ self.mass_matrix(q_rad) @ qd + pot)


def coxa_axis_inertia_kgm2(robot: Robot, leg: int, femur_rad: float, tibia_rad: float) -> float:
    """Inertia of the whole leg (links and the leg's tibia-tip payload) about the vertical coxa axis.

    The coxa link lies horizontally; femur and tibia are slender rods inclined by their link
    angles ``psi`` above the horizontal, so a rod's own inertia about the vertical through its
    COM is ``I_com cos^2(psi)``; every COM adds ``m r^2`` with ``r`` its horizontal distance from
    the axis. Rotor inertia is not included (the kernel adds ``J R^2``).
    """
    links, dh = robot.links, robot.dh
    a1, a2, a3 = dh['coxa'].a_m, dh['femur'].a_m, dh['tibia'].a_m
    psi2 = femur_rad + dh['femur'].theta_off_rad
    psi23 = psi2 + tibia_rad + dh['tibia'].theta_off_rad
    c, f, t = links['coxa'], links['femur'], links['tibia']
    r_c = c.com_from_joint_m
    r_f = a1 + f.com_from_joint_m * math.cos(psi2)
    r_t = a1 + a2 * math.cos(psi2) + t.com_from_joint_m * math.cos(psi23)
    r_tip = a1 + a2 * math.cos(psi2) + a3 * math.cos(psi23)
    inertia = (c.inertia_about_com_kgm2 + c.mass_kg * r_c ** 2
               + f.inertia_about_com_kgm2 * math.cos(psi2) ** 2 + f.mass_kg * r_f ** 2
               + t.inertia_about_com_kgm2 * math.cos(psi23) ** 2 + t.mass_kg * r_t ** 2)
    return inertia + robot.leg_payload_kg(leg) * r_tip ** 2


class CoxaModel(LegModel):
    """The coxa joint as a 1-DOF servo-driven rotation about the vertical axis (no gravity).

    The leg is treated as rigid while the coxa turns: its inertia about the axis is taken at the
    femur/tibia pose ``femur_tibia_rad`` (:func:`coxa_axis_inertia_kgm2`). It reuses the leg
    kernel with the second joint replaced by a massless, uncommanded dummy that stays at tick
    ``center`` (zero torque), so every effect (friction, damping, saturation, dead-band,
    backlash) acts exactly as on femur and tibia.
    """

    def __init__(self, robot: Robot, leg: int, femur_tibia_rad=(0.0, 0.0), substeps: int = 1):
        super().__init__(robot, leg, substeps=substeps)
        s = robot.servo
        e = robot.joint_effects(joint_name(leg, 'coxa'))
        p = self.params
        p[[P_M1, P_LC1, P_M2, P_LC2, P_I2, P_A2, P_G]] = 0.0
        p[P_I1] = coxa_axis_inertia_kgm2(robot, leg, float(femur_tibia_rad[0]), float(femur_tibia_rad[1]))
        fc = s.reflected_coulomb_nm + e.extra_coulomb_nm
        self.terms = np.array([joint_terms(robot, joint_name(leg, 'coxa')), joint_terms(robot, '')])
        p[P_B2] = joint_damping_nms_per_rad(s, e, self.terms[0, T_DS])
        p[P_FC2] = fc
        p[P_FS2] = max(fc, e.static_friction_nm)
        p[P_TMAX2] = s.stall_torque_nm if e.torque_max_nm is None else min(s.stall_torque_nm, e.torque_max_nm)
        p[P_MARG2] = s.compliance_margin_ticks + e.deadband_margin_ticks
        p[P_PUNCH2] = s.punch_nm + e.extra_punch_nm
        p[P_BL2] = e.backlash_width_rad
        # dummy second joint: rotor only, no friction, no play, never commanded away from centre
        p[P_B3] = s.reflected_damping_nms_per_rad
        p[P_FC3] = p[P_FS3] = 0.0
        p[P_TMAX3] = s.stall_torque_nm
        p[P_MARG3] = 0.0
        p[P_PUNCH3] = 0.0
        p[P_BL3] = 0.0
        self.center_tick = float(s.center_tick)

    def rollout_coxa(self, q0_rad: float, qd0_rad_s: float, goal_ticks, gap0_rad: float = 0.0, i_ext=None) -> Rollout:
        """Simulate the coxa from ``q0`` with integer goal ticks per control period (shape (n,)).

        Returns a :class:`Rollout` whose column 0 is the coxa (column 1 is the dummy joint).
        """
        goals = np.asarray(goal_ticks, dtype=np.float64)
        if goals.ndim != 1:
            raise ValueError(f'coxa goal_ticks must have shape (n,), got {goals.shape}')
        two = np.empty((len(goals), 2))
        two[:, 0] = goals
        two[:, 1] = self.center_tick
        return self.rollout([q0_rad, 0.0], [qd0_rad_s, 0.0], two, gap0_rad=[gap0_rad, 0.0], i_ext=i_ext)


# ----------------------------------------------------------------------------- CalcModel
class SwingDownError(ValueError):
    """Bad input to the swing-down prediction (the message names it)."""


@dataclass(frozen=True)
class SwingDownPrediction:
    """Predictions at every femur read of Algorithm 1; arrays are indexed ``[step k, leg slot l]``."""

    legs: tuple[int, ...]
    t_con_s: float
    t_com_s: float
    epsilon_tick: float
    direction: np.ndarray          # (L,) +1/-1: sign of the femur motion
    t_read_s: np.ndarray           # (K, L) read instants relative to swing-down start
    theta_des_tick: np.ndarray     # (K, L) integer femur goal in effect (written at k t_con)
    theta_est_tick: np.ndarray     # (K, L) predicted femur tick at the read instant (continuous)
    err_est_tick: np.ndarray       # (K, L) predicted lag in the direction of motion
    threshold_tick: np.ndarray     # (K, L) Eq. 17: err_est + epsilon
    reached_fin: np.ndarray        # (K,) True once the goal has reached theta_fin
    rollouts: tuple[Rollout, ...]  # full 1 kHz trajectories per leg


def goal_fraction(k, n_interp: float, approach_from=1.0, approach_rate: float = 1.0):
    """Fraction of the path theta_init -> theta_fin of the goal written at step ``k`` (scalar or array).

    Eq. 15: ``(k + 1) / n_interp`` (``n_interp = t_des / t_con``), capped at 1. With an approach
    profile (``approach_rate`` < 1, the improved touchdown beside the paper's), the goal moves at
    the Eq. 15 rate up to the fraction ``approach_from`` (where the foot nears the expected ground)
    and at ``approach_rate`` times that rate from there on: the free-swing lag, and with it the push
    of a foot that has just touched, shrinks by the same factor. ``approach_rate`` 1 is Eq. 15
    exactly (the same float operations)."""
    u = (np.asarray(k, dtype=float) + 1.0) / n_interp
    if approach_rate < 1.0:
        u = np.where(u <= approach_from, u, approach_from + approach_rate * (u - approach_from))
    return np.minimum(u, 1.0)


def steps_to_fin(n_interp: float, approach_from=1.0, approach_rate: float = 1.0) -> int:
    """Steps until the goal of :func:`goal_fraction` reaches theta_fin (the largest over legs)."""
    a = np.minimum(np.asarray(approach_from, dtype=float), 1.0)
    u_fin = a + (1.0 - a) / approach_rate if approach_rate < 1.0 else np.ones_like(a)
    return int(math.ceil(float(np.max(u_fin)) * n_interp - 1e-9))


def check_approach(approach_from, approach_rate: float, n_legs: int) -> np.ndarray:
    """The approach profile's inputs validated: ``approach_from`` as an (L,) array in [0, 1]."""
    if not (math.isfinite(approach_rate) and 0.0 < approach_rate <= 1.0):
        raise SwingDownError(f'approach_rate must be in (0, 1], got {approach_rate!r}')
    a = np.broadcast_to(np.asarray(approach_from, dtype=float), (n_legs,)).copy()
    if not (np.isfinite(a).all() and (a >= 0.0).all() and (a <= 1.0).all()):
        raise SwingDownError(f'approach_from must be fractions in [0, 1], got {a.tolist()}')
    return a


def interpolated_goals(theta_init_tick, theta_fin_tick, t_des_s: float, t_con_s: float, n_steps: int,
                       approach_from=1.0, approach_rate: float = 1.0) -> np.ndarray:
    """Eq. 15 / Algorithm 1 lines 3 and 6: ``theta_des(k) = theta_init + (k+1) dtheta``, capped at theta_fin
    (with an approach profile: :func:`goal_fraction`; ``approach_from`` scalar or per leg, the
    leading axis of the inputs).

    Returns continuous goals of shape (n_steps, ...) matching the trailing shape of the inputs.
    """
    init = np.asarray(theta_init_tick, dtype=float)
    fin = np.asarray(theta_fin_tick, dtype=float)
    n_interp = t_des_s / t_con_s
    k = np.arange(n_steps).reshape((-1,) + (1,) * init.ndim)
    a = np.asarray(approach_from, dtype=float)
    a = a.reshape(a.shape + (1,) * (init.ndim - a.ndim)) if a.ndim else a
    frac = goal_fraction(k, n_interp, a, approach_rate)
    return init + frac * (fin - init)


def goals_per_period(goal_steps: np.ndarray, t_con_s: float, dt_s: float, n_periods: int) -> np.ndarray:
    """The goal in effect at each servo control period: the latest one written at or before it."""
    t = np.arange(n_periods) * dt_s
    k = np.floor(t / t_con_s + 1e-9).astype(int)
    return goal_steps[np.clip(k, 0, len(goal_steps) - 1)]


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


@njit(cache=True, nogil=True)
def _swing_down_kernel(params, q0, q_fin, qd0, gap0, n_interp, approach_from, approach_rate, n_reach, t_con, per_step,
                       t_com, read_delay, center,
                       rad_per_tick, epsilon, ticks, direction, reached, goal_buf, idx, out_t_read, out_des,
                       out_est, out_err, out_thr, out_q, out_qd, out_tau, out_gap):
    """CalcModel for all swinging legs in one call, allocating nothing (every array is the caller's).

    Returns False, and computes nothing, when an initial or final angle (``q0``, ``q_fin``: (L, 2)
    rad) is not finite. Otherwise per leg slot ``l``: the initial and final angles as continuous
    ticks into ``ticks`` (2, L, 2) (the operations of :func:`hexapod_model.servo.theta_to_tick`) and
    the sign of the femur motion into ``direction`` (L,); the Eq. 15 goals (with the approach profile
    ``approach_from[l]``, ``approach_rate``: :func:`goal_fraction`) into ``goal_buf``: when
    ``t_con`` is ``per_step`` whole servo periods, one row per step (L, K, 2), each held for
    ``per_step`` periods; otherwise (``per_step`` = 0) the goal in effect at each servo period (step
    ``k = floor(t / t_con)``, capped at the last step; (L, n, 2)); the legs simulated together by
    :func:`_rollout_legs` over the n periods of ``out_tau`` (``idx`` its (L,) scratch); then per step ``k``
    the read instant ``k t_con + l t_com``, the goal, the predicted tick at the (delayed) sample
    instant (linear interpolation between servo periods, as ``np.interp``), the lag in the
    direction of motion and the Eq. 17 threshold; ``reached`` (K,) whether step ``k``'s goal is
    theta_fin (``k + 1 >= n_reach``, the number of interpolation steps).
    """
    n_legs = params.shape[0]
    n_steps = out_des.shape[0]
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
    for k in range(n_steps):
        reached[k] = k + 1 >= n_reach
    n_periods = out_tau.shape[1]
    dt = params[0, P_DT]
    if per_step > 0:
        for l in range(n_legs):
            for k in range(n_steps):
                goal_buf[l, k, 0] = _eq15_goal(init_t[l, 0], fin_t[l, 0], k, n_interp, approach_from[l], approach_rate)
                goal_buf[l, k, 1] = _eq15_goal(init_t[l, 1], fin_t[l, 1], k, n_interp, approach_from[l], approach_rate)
        _rollout_legs(params, q0, qd0, goal_buf, per_step, out_q, out_qd, out_tau, gap0, out_gap, idx)
    else:
        for l in range(n_legs):
            k_prev = -1
            g2 = 0.0
            g3 = 0.0
            for j in range(n_periods):
                # the step whose goal is in effect: floor(j dt / t_con) (as goals_per_period), capped
                kk = min(int(math.floor(j * dt / t_con + 1e-9)), n_steps - 1)
                if kk != k_prev:
                    g2 = _eq15_goal(init_t[l, 0], fin_t[l, 0], kk, n_interp, approach_from[l], approach_rate)
                    g3 = _eq15_goal(init_t[l, 1], fin_t[l, 1], kk, n_interp, approach_from[l], approach_rate)
                    k_prev = kk
                goal_buf[l, j, 0] = g2
                goal_buf[l, j, 1] = g3
        _rollout_legs(params, q0, qd0, goal_buf, 1, out_q, out_qd, out_tau, gap0, out_gap, idx)
    last = n_periods            # out_q has n_periods + 1 rows on the grid j dt
    x_last = last * dt
    for l in range(n_legs):
        q = out_q[l]
        for k in range(n_steps):
            t = k * t_con + l * t_com
            out_t_read[k, l] = t
            x = t - read_delay[l]
            if x < 0.0:
                x = 0.0
            if x >= x_last:
                th = q[last, 0]
            else:
                j = int(x / dt)
                while j > 0 and j * dt > x:
                    j -= 1
                while j + 1 < last and (j + 1) * dt <= x:
                    j += 1
                xj = j * dt
                if x == xj:
                    th = q[j, 0]
                else:
                    th = (q[j + 1, 0] - q[j, 0]) / ((j + 1) * dt - xj) * (x - xj) + q[j, 0]
            des = _eq15_goal(init_t[l, 0], fin_t[l, 0], k, n_interp, approach_from[l], approach_rate)
            est = center + th / rad_per_tick
            out_des[k, l] = des
            out_est[k, l] = est
            out_err[k, l] = direction[l] * (des - est)
            out_thr[k, l] = out_err[k, l] + epsilon
    return True


def predict_swing_down(robot: Robot, legs, theta_init_rad, theta_fin_rad, t_des_s: float, t_com_s: float,
                       epsilon_tick: float = 3.0, n_steps: int | None = None, qd0_rad_s=None,
                       models: dict | None = None, read_delay_s=None, approach_from=1.0,
                       approach_rate: float = 1.0) -> SwingDownPrediction:
    """CalcModel for ``legs`` swinging down together, read sequentially in the given order.

    ``theta_init_rad``/``theta_fin_rad``: arrays (L, 2) of (femur, tibia) DH angles. ``n_steps``:
    control steps to predict (default: until theta_fin plus 20 % settling). ``models`` may carry
    cached :class:`LegModel` per leg. ``read_delay_s`` (L,) shifts each leg's reported sample
    earlier (a readout delay effect). ``approach_from`` (scalar or (L,)) and ``approach_rate``: the
    approach profile of the goals (:func:`goal_fraction`; rate 1 = Eq. 15).

    One compiled call (:func:`_swing_down_kernel`) expands the Eq. 15 goals, simulates every leg and
    samples the reads; Python only validates the input and allocates the result (one block).
    """
    legs = tuple(int(x) for x in legs)
    L = len(legs)
    if L == 0:
        raise SwingDownError('no legs given')
    init = np.asarray(theta_init_rad, dtype=float).reshape(L, 2)
    fin = np.asarray(theta_fin_rad, dtype=float).reshape(L, 2)
    for name, v in (('t_des_s', t_des_s), ('t_com_s', t_com_s), ('epsilon_tick', epsilon_tick)):
        if not math.isfinite(v) or (name != 'epsilon_tick' and v <= 0):
            raise SwingDownError(f'{name} must be a finite positive number, got {v!r}')
    approach = check_approach(approach_from, approach_rate, L)
    servo = robot.servo
    t_con = L * t_com_s                                         # Algorithm 1, line 1
    n_fin = steps_to_fin(t_des_s / t_con, approach, approach_rate)
    if n_steps is None:
        n_steps = int(math.ceil(n_fin * 1.2)) + 1
    qd0 = np.zeros((L, 2)) if qd0_rad_s is None else np.asarray(qd0_rad_s, dtype=float).reshape(L, 2)
    if not np.all(np.isfinite(qd0)):
        raise SwingDownError('initial joint speeds contain NaN or infinity')
    delay = np.zeros(L) if read_delay_s is None else np.asarray(read_delay_s, dtype=float).reshape(L)
    dt = servo.control_period_s
    t_read_max = (n_steps - 1) * t_con + (L - 1) * t_com_s   # lines 8-15: the last read
    n_periods = int(math.ceil(t_read_max / dt)) + 2
    params = np.empty((L, N_PARAMS))
    gap0 = np.zeros((L, 2))
    for slot, leg in enumerate(legs):
        model = (models or {}).get(leg) or LegModel(robot, leg)
        params[slot] = model.params
        if model.params[P_BL2] > 0.0 or model.params[P_BL3] > 0.0:
            gap0[slot] = model.default_gap_rad(init[slot]) if np.isfinite(init[slot]).all() else 0.0
    ratio = t_con / dt
    per_step = int(round(ratio)) if abs(ratio - round(ratio)) < 1e-9 else 0   # t_con in whole servo periods
    goal_rows = n_steps if per_step else n_periods
    # the result in one allocation: 5 (K, L) tables, the init/fin ticks (2, L, 2), the direction (L,),
    # per leg q/qd/gap (n+1, 2) and tau (n, 2); the kernel's scratch (the goals) at its end
    kl = 5 * n_steps * L
    rows = L * (n_periods + 1) * 2
    block = np.empty(kl + 5 * L + 3 * rows + L * n_periods * 2 + L * goal_rows * 2)
    tables = block[:kl].reshape(5, n_steps, L)
    ticks = block[kl:kl + 4 * L].reshape(2, L, 2)
    direction = block[kl + 4 * L:kl + 5 * L]
    o = kl + 5 * L
    q, qd, gap = (block[o + i * rows:o + (i + 1) * rows].reshape(L, n_periods + 1, 2) for i in range(3))
    o += 3 * rows
    tau = block[o:o + L * n_periods * 2].reshape(L, n_periods, 2)
    goal_buf = block[o + L * n_periods * 2:].reshape(L, goal_rows, 2)
    reached = np.empty(n_steps, dtype=np.bool_)
    if not _swing_down_kernel(params, init, fin, qd0, gap0, float(t_des_s / t_con), approach, float(approach_rate),
                              n_fin, t_con, per_step,
                              float(t_com_s), delay, float(servo.center_tick), float(servo.rad_per_tick),
                              float(epsilon_tick), ticks, direction, reached, goal_buf, np.empty(L, np.int64),
                              tables[0], tables[1], tables[2], tables[3], tables[4], q, qd, tau, gap):
        raise SwingDownError('initial or final joint angles contain NaN or infinity')
    rollouts = tuple(Rollout(dt, q[slot], qd[slot], tau[slot], gap[slot]) for slot in range(L))
    return SwingDownPrediction(
        legs=legs, t_con_s=t_con, t_com_s=t_com_s, epsilon_tick=float(epsilon_tick), direction=direction,
        t_read_s=tables[0], theta_des_tick=tables[1], theta_est_tick=tables[2], err_est_tick=tables[3],
        threshold_tick=tables[4], reached_fin=reached, rollouts=rollouts)
