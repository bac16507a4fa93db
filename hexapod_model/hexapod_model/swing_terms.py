"""The swing-down model with the dictionary's torque terms (:mod:`hexapod_model.dictionary`). Pure numba.

A leg with any dictionary term on its femur or tibia (or a coxa with one on it) is stepped by
:func:`rollout_terms` instead of the fast kernel of :mod:`hexapod_model.swing_model`. Per control
period, before the substeps, it computes from the state at the period's start:

- the firmware torque of :func:`hexapod_model.servo.firmware_torque_scalar` times the joint's
  ``torque_scale`` (a weak motor), then the supply sag: with ``S`` the total stall current of the
  robot's servos (this leg's, ``|tau| / (K R)``, plus ``i_ext``, the rest of the robot's, given per
  period) the drive is divided by ``1 + R S / V``;
- the cable spring's torque ``-k (theta - theta_rest)``, added to the drive;
- the extra Coulomb friction of periodic and load-proportional friction, added to the joint's
  Coulomb and break-away levels.

All of these are held over the period, like the firmware torque (the MuJoCo sim applies them at
the same instants). The substep itself is the fast kernel's rigid substep, so without terms the
result is the fast kernel's to the bit; the back-EMF damping of a weak motor is in the parameter
vector (``swing_model.LegModel``). Gear backlash on the same leg is not modelled with terms.
"""
from __future__ import annotations

import math

import numpy as np

from hexapod_model.dictionary import N_TERMS, T_K, T_MU, T_PA, T_PP, T_PPH, T_REST, T_TS
from hexapod_model.swing_common import _FASTMATH, P_CONTROL, P_OFF2, P_OFF3, P_SUBSTEPS, _servo_torques, njit
from hexapod_model.swing_kernel import _rigid_constants, _rigid_substep, _rotate


@njit(cache=True, fastmath=_FASTMATH, nogil=True, inline='always')
def _extra_friction(tv, j, q, tau):
    """Extra Coulomb friction [N m] of joint ``j``'s periodic and load-proportional terms."""
    x = tv[j, T_MU] * abs(tau)
    if tv[j, T_PA] > 0.0:
        x += tv[j, T_PA] * 0.5 * (1.0 + math.cos(2.0 * math.pi * q / tv[j, T_PP] - tv[j, T_PPH]))
    return x


@njit(cache=True, fastmath=_FASTMATH, nogil=True)
def _rollout_terms_kernel(p, tv, r_over_v, inv_kt, i_ext, q0, qd0, goals, out_q, out_qd, out_tau):
    """One rigid leg with dictionary terms ``tv`` (2, N_TERMS) over ``out_tau.shape[0]`` periods.

    ``goals`` (n, 2) one row per period; ``i_ext`` (n,) the rest of the robot's stall current [A];
    ``r_over_v``: supply resistance over supply voltage [1/A]; ``inv_kt``: 1 / (K R) [A / N m].
    Writes ``out_q``/``out_qd`` (n + 1, 2) and ``out_tau`` (n, 2) the drive held over each period.
    """
    c = _rigid_constants(p)
    n_sub = int(p[P_SUBSTEPS])
    q2, q3, v2, v3 = q0[0], q0[1], qd0[0], qd0[1]
    c2, s2 = math.cos(q2 + p[P_OFF2]), math.sin(q2 + p[P_OFF2])
    c3, s3 = math.cos(q3 + p[P_OFF3]), math.sin(q3 + p[P_OFF3])
    out_q[0, 0], out_q[0, 1], out_qd[0, 0], out_qd[0, 1] = q2, q3, v2, v3
    last = goals.shape[0] - 1
    for k in range(out_tau.shape[0]):
        g = min(k, last)
        t2, t3 = _servo_torques(p, goals[g, 0], goals[g, 1], q2, q3)
        t2 *= tv[0, T_TS]
        t3 *= tv[1, T_TS]
        if r_over_v > 0.0 and p[P_CONTROL] > 0.5:
            sag = 1.0 / (1.0 + r_over_v * (i_ext[k] + (abs(t2) + abs(t3)) * inv_kt))
            t2 *= sag
            t3 *= sag
        x2 = _extra_friction(tv, 0, q2, t2)
        x3 = _extra_friction(tv, 1, q3, t3)
        cc = (c[0], c[1], c[2], c[3], c[4], c[5], c[6], c[7], c[8], c[9],
              c[10] + x2, c[11] + x3, c[12] + x2, c[13] + x3)
        d2 = t2 - tv[0, T_K] * (q2 - tv[0, T_REST])
        d3 = t3 - tv[1, T_K] * (q3 - tv[1, T_REST])
        for _ in range(n_sub):
            q2, q3, v2, v3, nc2, ns2, nc3, ns3, e2, e3 = _rigid_substep(cc, d2, d3, q2, q3, v2, v3, c2, s2, c3, s3)
            if max(abs(e2), abs(e3)) >= 0.01:
                nc2, ns2 = _rotate(c2, s2, e2)
                nc3, ns3 = _rotate(c3, s3, e3)
            c2, s2, c3, s3 = nc2, ns2, nc3, ns3
        out_tau[k, 0] = t2
        out_tau[k, 1] = t3
        out_q[k + 1, 0], out_q[k + 1, 1], out_qd[k + 1, 0], out_qd[k + 1, 1] = q2, q3, v2, v3


def rollout_terms(params: np.ndarray, terms: np.ndarray, supply: tuple[float, float], q0, qd0, goals,
                  i_ext=None):
    """Simulate one leg with dictionary terms: ``params`` the leg's packed parameter vector,
    ``terms`` (2, N_TERMS), ``supply`` (R / V, 1 / (K R)), ``goals`` (n, 2) integer goal ticks per
    period, ``i_ext`` (n,) the rest of the robot's stall current [A] (default none).
    Returns ``(q (n + 1, 2), qd (n + 1, 2), tau (n, 2))``."""
    goals = np.ascontiguousarray(goals, dtype=np.float64)
    n = len(goals)
    tv = np.ascontiguousarray(terms, dtype=np.float64).reshape(2, N_TERMS)
    ext = np.zeros(n) if i_ext is None else np.ascontiguousarray(i_ext, dtype=np.float64)
    if len(ext) < n:
        ext = np.concatenate([ext, np.full(n - len(ext), ext[-1] if len(ext) else 0.0)])
    q = np.empty((n + 1, 2))
    qd = np.empty((n + 1, 2))
    tau = np.empty((n, 2))
    _rollout_terms_kernel(params, tv, float(supply[0]), float(supply[1]), ext,
                          np.asarray(q0, dtype=np.float64).reshape(2), np.asarray(qd0, dtype=np.float64).reshape(2),
                          goals, q, qd, tau)
    return q, qd, tau
