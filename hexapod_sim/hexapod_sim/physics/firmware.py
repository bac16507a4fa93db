"""Compiled inner loop of the simulator: AX-12A firmware ticks interleaved with MuJoCo steps. No rclpy.

At 1 kHz with a 1 ms physics step, per-step Python (a dozen small numpy calls plus the
``mujoco.mj_step`` binding) costs as much as the physics itself. :func:`run` does the whole loop in
one numba-compiled call and calls MuJoCo's C ``mj_step`` directly (linked by symbol from the
library the bindings load, on the same ``MjModel``/``MjData`` they hold), returning to Python only
when the caller's target step is reached or a buffer needs emptying. It is bit-for-bit the same computation as stepping
with ``mujoco.mj_step`` from Python (a test checks it).

What it does per physics step, in order (the simulator's timing convention):

1. at a firmware tick (every ``spm`` steps): read each servo's output angle (motor hinge plus
   backlash play), quantise it exactly like :func:`hexapod_model.servo.quantize_tick`, look up the
   torque for ``goal - present`` in the table built from
   :func:`hexapod_model.servo.firmware_torque_nm`, write it to the actuator (held until the next
   tick), buffer torque and speed for the battery/thermal model, and switch the friction loss of
   joints with static friction: the break-away level for a joint at rest, the Coulomb level for
   one that slips. At rest means slower than ``v_stick``, or moving the other way than at the
   previous tick (its velocity passed through zero in between: a reversal meets static friction
   wherever in the step the zero falls, as in the swing-down model), or held at the previous tick
   and slowing down (MuJoCo's soft friction constraint brings a held joint to rest over a few
   steps; it breaks away only when its speed grows, i.e. the drive exceeds the break-away level);
2. record the output angles in the history ring (readout-delay effect), when enabled;
3. record the trunk orientation and angular velocity, ``mj_step``, record the trunk's linear
   acceleration that step computed (all for the state at the start of the step: the IMU).
"""
from __future__ import annotations

import glob
import math
import os

import llvmlite.binding as llvm
import mujoco
import numpy as np
from numba import njit, types

# indices of the loop state vector (int64): current step, step of the next firmware tick,
# rows used in the power window, rows used in the sensor buffer
ST_STEP, ST_NEXT_FW, ST_WIN_N, ST_SENS_N = range(4)


def _mujoco_library() -> str:
    """Path of the libmujoco the Python bindings link against (it ships inside the wheel)."""
    here = os.path.dirname(mujoco.__file__)
    paths = sorted(glob.glob(os.path.join(here, 'libmujoco.so*')) + glob.glob(os.path.join(here, 'libmujoco*.dylib')))
    if not paths:
        raise ImportError(f'libmujoco not found next to the mujoco Python package ({here}); the compiled '
                          'simulation loop needs it')
    return paths[0]


# Make mj_step resolvable by name for compiled code (the same, already loaded library the bindings
# use), and declare it: mj_step(const mjModel*, mjData*), pointers passed as integer addresses.
# Linking by symbol name (not by a ctypes pointer) keeps the kernel cacheable on disk.
llvm.load_library_permanently(_mujoco_library())
_mj_step = types.ExternalFunction('mj_step', types.void(types.int64, types.int64))


@njit(cache=True, inline='always')
def quantize1(raw_tick, max_tick):
    """One value of :func:`hexapod_model.servo.quantize_tick`: nearest integer (half to even), clipped."""
    p = np.rint(raw_tick)
    if p < 0.0:
        p = 0.0
    elif p > max_tick:
        p = max_tick
    return np.int64(p)


@njit(cache=True)
def quantize_array(raw_tick, max_tick):
    """:func:`quantize1` over an array (for tests and callers outside the loop)."""
    out = np.empty(raw_tick.shape[0], dtype=np.int64)
    for i in range(raw_tick.shape[0]):
        out[i] = quantize1(raw_tick[i], max_tick)
    return out


# rows of the per-joint integer table passed to run()
J_QPOS, J_PLAY, J_DOF, J_ACT, J_ROW_OFF, J_GOAL_IDX = range(6)
# rows of the per-joint float table
F_SCALE, F_BASE = range(2)
# dictionary terms (hexapod_model.dictionary) of the joints that have one: rows of the integer table
# (joint index, dof, 1 when the joint also has static friction) and of the float table (spring
# stiffness and rest angle, periodic friction amplitude, period and phase, load-friction coefficient,
# the joint's friction loss without them); supply: (R / V, 1 / (K R)) of the supply sag, 0 without one
D_JOINT, D_DOF, D_STICK = range(3)
DF_K, DF_REST, DF_PA, DF_PP, DF_PPH, DF_MU, DF_BASE = range(7)


@njit(cache=True, inline='always')
def output_angle(qpos, jint, i):
    """Joint ``i``'s servo output angle: its motor hinge plus its backlash play, if any."""
    q = qpos[jint[J_QPOS, i]]
    if jint[J_PLAY, i] >= 0:
        q += qpos[jint[J_PLAY, i]]
    return q


@njit(cache=True)
def dictionary_pass(win_row, qpos, ctrl, dof_frictionloss, qfrc_applied, jint, tau_out, win_tau, dint, dflt, supply):
    """The dictionary's torque terms at a firmware tick, after the firmware torques (see
    :mod:`hexapod_model.swing_terms`, the model's twin): the supply sag divides every servo's torque by
    ``1 + R S / V`` (``S`` the total stall current); per joint with terms, the cable spring's torque
    goes to ``qfrc_applied`` and periodic and load friction are added to the joint's friction loss
    (its static-friction level at rest). All held until the next tick."""
    n = jint.shape[1]
    if supply[0] > 0.0:
        s = 0.0
        for i in range(n):
            s += abs(tau_out[i])
        f = 1.0 / (1.0 + supply[0] * s * supply[1])
        for i in range(n):
            tau_out[i] *= f
            ctrl[jint[J_ACT, i]] = tau_out[i]
            win_tau[win_row, i] = tau_out[i]
    for k in range(dint.shape[1]):
        i = dint[D_JOINT, k]
        q = output_angle(qpos, jint, i)
        dof = dint[D_DOF, k]
        qfrc_applied[dof] = -dflt[DF_K, k] * (q - dflt[DF_REST, k])
        x = dflt[DF_MU, k] * abs(tau_out[i])
        if dflt[DF_PA, k] > 0.0:
            x += dflt[DF_PA, k] * 0.5 * (1.0 + math.cos(2.0 * math.pi * q / dflt[DF_PP, k] - dflt[DF_PPH, k]))
        base = dof_frictionloss[dof] if dint[D_STICK, k] > 0 else dflt[DF_BASE, k]
        dof_frictionloss[dof] = base + x


@njit(cache=True)
def write_goals(idx, vals, lim_lo, lim_hi, scale, base, max_tick, angle_bit, error_bits, goal, jint):
    """A sync write's goals (angles ``vals`` [rad] of joints ``idx``) into the loop's tables, in one call.

    Returns the position in ``idx`` of the first non-finite value, and writes nothing then; else -1.
    Per joint, as the AX-12A with its CW/CCW angle limits: the angle clamped to ``[lim_lo, lim_hi]``,
    the angle-limit bit ``angle_bit`` of ``error_bits`` set when it was clamped and cleared when not,
    the goal tick quantised (:func:`quantize1` of ``angle * scale + base``) into ``goal`` and its
    torque-table index ``goal + max_tick`` into ``jint[J_GOAL_IDX]``.
    """
    for k in range(idx.shape[0]):
        if not math.isfinite(vals[k]):
            return k
    for k in range(idx.shape[0]):
        i = idx[k]
        v = min(max(vals[k], lim_lo[i]), lim_hi[i])
        if v != vals[k]:
            error_bits[i] |= angle_bit
        else:
            error_bits[i] &= ~angle_bit
        g = quantize1(v * scale[i] + base[i], max_tick)
        goal[i] = g
        jint[J_GOAL_IDX, i] = g + np.int64(max_tick)
    return -1


@njit(cache=True, inline='always')
def firmware_tick(win_n, max_tick, qpos, qvel, ctrl, jint, jflt, table, win_tau, win_omega, tau_out):
    """Every servo's firmware at a tick: the present tick quantised from its output angle, the torque
    for ``goal - present`` from the table into the actuator (held until the next tick), and the
    torque and speed into row ``win_n`` of the power window."""
    for i in range(jint.shape[1]):
        present = quantize1(output_angle(qpos, jint, i) * jflt[F_SCALE, i] + jflt[F_BASE, i], max_tick)
        tau = table[jint[J_ROW_OFF, i] + jint[J_GOAL_IDX, i] - present]
        ctrl[jint[J_ACT, i]] = tau
        tau_out[i] = tau
        win_tau[win_n, i] = tau
        win_omega[win_n, i] = qvel[jint[J_DOF, i]]


@njit(cache=True, inline='always')
def static_friction_tick(v_stick, qvel, dof_frictionloss, jint, stick_int, stick_flt):
    """The friction loss of each joint with static friction at a tick: the break-away level when it
    is at rest (slower than ``v_stick``, reversed since the last tick, or held there and slowing
    down), the Coulomb level when it slips; its velocity and state kept for the next tick."""
    for k in range(stick_int.shape[1]):
        v = qvel[jint[J_DOF, stick_int[0, k]]]
        v0 = stick_flt[2, k]
        held = (abs(v) < v_stick or v * v0 < 0.0
                or (stick_flt[3, k] > 0.0 and abs(v) < abs(v0)))
        if held:
            dof_frictionloss[stick_int[1, k]] = stick_flt[0, k]
        else:
            dof_frictionloss[stick_int[1, k]] = stick_flt[1, k]
        stick_flt[2, k] = v
        stick_flt[3, k] = 1.0 if held else 0.0


@njit(cache=True)
def run(target, m_ptr, d_ptr, st, spm, max_tick, v_stick, imu_adr,
        qpos, qvel, qacc, ctrl, dof_frictionloss,
        jint, jflt, table, stick_int, stick_flt,
        win_tau, win_omega, tau_out, sens_buf, sens_step, hist, qfrc_applied, dint, dflt, supply):
    """Advance until ``st[ST_STEP] == target``, or earlier when the power window is full at a
    firmware tick or the sensor buffer is full (the caller empties them and calls again).

    ``jint`` (6, n): qpos address, backlash qpos address (-1 none), dof address, actuator index,
    torque-table row offset (row * width; the zero row = torque off), goal tick + max_tick.
    ``jflt`` (2, n): raw-tick scale (direction / rad_per_tick) and base (centre + offset).
    ``stick_int`` (2, k): joint index and dof of joints with static friction; ``stick_flt`` (4, k):
    their break-away and Coulomb friction [N m], and the loop's state of them: velocity at the
    previous tick and whether they were held there (1.0) or slipping (0.0).
    ``imu_adr``: qpos address of the trunk quaternion, qvel address of its angular velocity (body
    frame) and of its linear velocity (world frame), -1 for a fixed base. ``qfrc_applied``, ``dint``,
    ``dflt``, ``supply``: the dictionary's terms (:func:`dictionary_pass`; no joints and no supply = none). Per step the row of
    ``sens_buf`` gets quaternion (4), linear acceleration in the world frame (3, ``qacc`` of the
    step) and angular velocity (3), all for the state at the start of the step.
    """
    n = jint.shape[1]
    n_win = win_tau.shape[0]
    n_sens = sens_buf.shape[0]
    n_hist = hist.shape[0]
    qa, wa, la = imu_adr[0], imu_adr[1], imu_adr[2]
    step = st[ST_STEP]
    next_fw = st[ST_NEXT_FW]
    win_n = st[ST_WIN_N]
    sens_n = st[ST_SENS_N]
    while step < target:
        if step == next_fw:
            if win_n == n_win:
                break
            firmware_tick(win_n, max_tick, qpos, qvel, ctrl, jint, jflt, table, win_tau, win_omega, tau_out)
            static_friction_tick(v_stick, qvel, dof_frictionloss, jint, stick_int, stick_flt)
            if dint.shape[1] > 0 or supply[0] > 0.0:
                dictionary_pass(win_n, qpos, ctrl, dof_frictionloss, qfrc_applied, jint, tau_out, win_tau,
                                dint, dflt, supply)
            win_n += 1
            next_fw = step + spm
        if n_hist > 0:
            row = step % n_hist
            for i in range(n):
                hist[row, i] = output_angle(qpos, jint, i)
        if n_sens > 0 and sens_n == n_sens:
            break
        if n_sens > 0 and qa >= 0:
            for j in range(4):
                sens_buf[sens_n, j] = qpos[qa + j]
            for j in range(3):
                sens_buf[sens_n, 7 + j] = qvel[wa + j]
        _mj_step(m_ptr, d_ptr)
        if n_sens > 0:
            if qa >= 0:
                for j in range(3):
                    sens_buf[sens_n, 4 + j] = qacc[la + j]    # computed by this step for its start state
            sens_step[sens_n] = step
            sens_n += 1
        step += 1
    st[ST_STEP] = step
    st[ST_NEXT_FW] = next_fw
    st[ST_WIN_N] = win_n
    st[ST_SENS_N] = sens_n
