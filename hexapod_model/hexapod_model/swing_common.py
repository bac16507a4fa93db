"""What every swing-down kernel shares (:mod:`hexapod_model.swing_model`): the indices into the
packed parameter vector, numba's compile flags, the rest threshold and the servo law. Pure numpy/numba.
"""
from __future__ import annotations

import numpy as np

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

V_STICK = 1e-7  # rad/s: below this a joint counts as at rest (break-away friction applies)


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
