"""The tables :class:`~hexapod_sim.physics.plant.HexapodSim` is built with: per joint, from the robot
description and the MuJoCo model, what the compiled firmware loop (:mod:`hexapod_sim.physics.firmware`) and
the bus reads look up.

Effects of the robot description are emulated in these tables or in the MJCF (:mod:`hexapod_sim.physics.mjcf`):
static friction (per-tick switch of the joint's friction loss between break-away and Coulomb
level; a velocity reversal between two ticks counts as rest, :mod:`hexapod_sim.physics.firmware`),
torque saturation (per-servo torque limit), compliance dead-band (margin), punch, goal latency
(a written goal acts from the first step at or after its write plus the latency), readout delay
(positions come from a history buffer), plus the MJCF-level coulomb friction, viscous damping,
payload and backlash; the dictionary's terms (:mod:`hexapod_model.dictionary`: a cable spring, periodic and
load friction, a supply sag, a weak motor) per firmware tick (:func:`firmware.dictionary_pass`) and in the
torque table and MJCF. Their values never leave the plant except as physics.
"""
from __future__ import annotations

import math

import numpy as np

from hexapod_model.description import ALL_JOINTS, LEGS, Robot
from hexapod_model.dictionary import T_K, T_MU, T_PA, T_PP, T_PPH, T_REST, T_TS, joint_terms, supply_resistance_ohm
from hexapod_model.joints import JOINTS
from hexapod_model.servo import firmware_torque_nm
from hexapod_sim.physics import firmware

POWER_WINDOW = 50             # firmware ticks per battery/thermal evaluation block (50 ms)
V_STICK_RAD_S = 1e-3          # static friction: a joint slower than this (or reversing) counts as at rest
SENSOR_ROWS = 256             # physics steps of sensor data buffered by the compiled loop


class PlantTables:
    """The set-up of :class:`~hexapod_sim.physics.plant.HexapodSim`'s tables (a base class of it): called once
    its model, data, robot, servo and timing are in place."""

    def _build_tables(self) -> None:
        s, m, n = self._servo, self.model, len(ALL_JOINTS)
        self._build_joint_maps(s, m)
        terms, fc, fs = self._build_firmware_tables(s, m, n)
        self._build_power_tables(s, n)
        self._build_loop_tables(s, m, n, terms, fc, fs)
        self._build_read_tables(s, m, n)

    def _build_joint_maps(self, s, m) -> None:
        """MuJoCo addresses of every joint, the bus's tick mapping and the joint limits."""
        self.joint_names = ALL_JOINTS
        self._index = {name: i for i, name in enumerate(ALL_JOINTS)}
        self._qadr = np.array([m.joint(j).qposadr[0] for j in ALL_JOINTS])
        self._dadr = np.array([m.joint(j).dofadr[0] for j in ALL_JOINTS])
        self._act = np.array([m.actuator(j).id for j in ALL_JOINTS])
        play = {j: m.joint(j + '_backlash').qposadr[0] for j in self.scene.backlash_joints}
        self._play_qadr = np.array([play.get(j, -1) for j in ALL_JOINTS], dtype=np.int64)

        bus = {bj.joint: bj for bj in self.robot.bus.joints}
        self._dir = np.array([float(bus[j].direction) for j in ALL_JOINTS])
        self._offset = np.array([float(bus[j].offset_ticks) for j in ALL_JOINTS])
        self._servo_ids = np.array([bus[j].servo_id for j in ALL_JOINTS])
        # raw servo tick = center + dir * theta / rad_per_tick + offset
        self._tick_scale = self._dir / s.rad_per_tick
        self._tick_base = s.center_tick + self._offset
        lims = np.array([self.robot.joint_limits(j) for j in ALL_JOINTS])
        self._lim_lo, self._lim_hi = lims[:, 0], lims[:, 1]

    def _build_firmware_tables(self, s, m, n: int):
        """The firmware's torque table, static friction, goal latency and readout delay of every servo.
        -> (the dictionary's terms per joint, Coulomb friction loss, break-away friction)."""
        eff = [self.robot.joint_effects(j) for j in JOINTS]
        self._tmax = np.array([s.stall_torque_nm if e.torque_max_nm is None else min(s.stall_torque_nm, e.torque_max_nm)
                               for e in eff])
        self._margin = np.array([s.compliance_margin_ticks + e.deadband_margin_ticks for e in eff], dtype=float)
        self._punch = np.array([s.punch_nm + e.extra_punch_nm for e in eff])
        # The firmware law depends on the integer error goal - present only (-max..max ticks), so the
        # torque of every possible error is computed once, through firmware_torque_nm itself, per servo
        # (joint direction folded in); row n (the last) is all zeros for a servo with torque off.
        self._err_off = s.max_tick
        err = np.arange(-s.max_tick, s.max_tick + 1, dtype=float)
        table = np.zeros((n + 1, err.size))
        terms = np.array([joint_terms(self.robot, j) for j in JOINTS])
        for i in range(n):
            table[i] = self._dir[i] * firmware_torque_nm(err, 0.0, s.gain_nm_per_tick, self._tmax[i], self._margin[i],
                                                         self._punch[i]) * terms[i, T_TS]   # a weak motor's drive
        self._torque_table = table.ravel()             # flat: index = row * width + error + max_tick
        self._table_width = err.size
        fc = np.array([m.dof_frictionloss[self._dadr[i]] for i in range(n)])
        fs = np.array([max(f, e.static_friction_nm) for f, e in zip(fc, eff)])
        self._stick_idx = np.flatnonzero(fs > fc)
        self._stick_dadr = self._dadr[self._stick_idx]
        self._fric_coulomb = fc[self._stick_idx]
        self._fric_static = fs[self._stick_idx]
        # goal latency (servo-law effect): a goal written at step k acts from step k + lag on
        self._goal_lag = np.array([int(math.ceil(e.goal_latency_s / self.dt - 1e-9)) for e in eff], dtype=np.int64)
        delay = np.array([e.readout_delay_s for e in eff])
        self._delay_steps = np.rint(delay / self.dt).astype(np.int64)
        # history ring of output angles per physics step (only with a readout delay)
        n_hist = int(self._delay_steps.max()) + 2 if np.any(self._delay_steps > 0) else 0
        self._hist = np.zeros((n_hist, n))
        return terms, fc, fs

    def _build_power_tables(self, s, n: int) -> None:
        """The battery's and the thermal model's buffers and weights."""
        # battery and thermal bookkeeping: torque and speed of every firmware tick are buffered and
        # evaluated in blocks of POWER_WINDOW ticks (exact per tick, one vectorised call per block)
        self._win_tau = np.zeros((POWER_WINDOW, n))
        self._win_omega = np.zeros((POWER_WINDOW, n))
        decay = math.exp(-s.control_period_s / s.thermal_time_constant_s)
        # T after k ticks of constant input: T_inf + (T0 - T_inf) decay^k; weights of each tick's T_inf
        self._therm_w = {k: (decay ** k, (1 - decay) * decay ** np.arange(k - 1, -1, -1))
                         for k in range(1, POWER_WINDOW + 1)}

    def _build_loop_tables(self, s, m, n: int, terms: np.ndarray, fc: np.ndarray, fs: np.ndarray) -> None:
        """The compiled loop's packed tables, sensor buffers and arguments."""
        # IMU at the trunk origin from the free joint: orientation qpos[3:7], angular velocity (body
        # frame) qvel[3:6], linear acceleration (world) qacc[0:3]; equal to MuJoCo's framequat/gyro/
        # accelerometer sensors (a test checks it) without their cost (mj_rnePostConstraint each step)
        if self.scene.fixed_base:
            self._imu_adr = np.array([-1, -1, -1], dtype=np.int64)
        else:
            root = m.joint('root')
            self._imu_adr = np.array([root.qposadr[0] + 3, root.dofadr[0] + 3, root.dofadr[0]], dtype=np.int64)
        self._sens_buf = np.zeros((SENSOR_ROWS if self._imu_period_steps else 0, 10))
        self._sens_step = np.zeros(SENSOR_ROWS, dtype=np.int64)
        self._st = np.zeros(4, dtype=np.int64)             # compiled-loop state (firmware.ST_*)
        self._tau = np.zeros(n)
        self._stick_j = self._stick_idx.astype(np.int64)
        self._stick_dadr = self._stick_dadr.astype(np.int64)
        self._qadr = self._qadr.astype(np.int64)
        self._dadr = self._dadr.astype(np.int64)
        self._act = self._act.astype(np.int64)
        # packed per-joint tables of the compiled loop (updated in place: the loop holds references)
        self._jint = np.zeros((6, n), dtype=np.int64)
        self._jint[firmware.J_QPOS] = self._qadr
        self._jint[firmware.J_PLAY] = self._play_qadr
        self._jint[firmware.J_DOF] = self._dadr
        self._jint[firmware.J_ACT] = self._act
        self._jflt = np.array([self._tick_scale, self._tick_base])
        self._stick_int = np.array([self._stick_j, self._stick_dadr], dtype=np.int64).reshape(2, -1)
        self._stick_flt = np.array([self._fric_static, self._fric_coulomb, np.zeros_like(self._fric_static),
                                    np.ones_like(self._fric_static)], dtype=float).reshape(4, -1)
        self._dint, self._dflt, self._supply = dictionary_tables(self.robot, terms, self._dadr, fc, fs > fc)
        d_ = self.data
        self._loop_args = (m._address, d_._address, self._st, self._spm, float(s.max_tick), V_STICK_RAD_S,
                           self._imu_adr, d_.qpos, d_.qvel, d_.qacc, d_.ctrl, m.dof_frictionloss,
                           self._jint, self._jflt, self._torque_table, self._stick_int, self._stick_flt,
                           self._win_tau, self._win_omega, self._tau, self._sens_buf, self._sens_step, self._hist,
                           d_.qfrc_applied, self._dint, self._dflt, self._supply)

    def _build_read_tables(self, s, m, n: int) -> None:
        """What a bus read, the trunk's pose and the feet's contacts look up."""
        # per-joint constants of a read as Python numbers (no numpy-scalar overhead per read)
        self._qpos = self.data.qpos                            # a view on MjData: stable for its lifetime
        self._max_tick = int(s.max_tick)
        self._read_consts = [(float(self._tick_scale[i]), float(self._tick_base[i]), int(self._qadr[i]),
                              int(self._play_qadr[i]), int(self._delay_steps[i])) for i in range(n)]
        self._trunk = m.body('trunk').id
        self._free_qadr = None if self.scene.fixed_base else m.joint('root').qposadr[0]
        self._foot_geom = {m.geom(f'leg{leg}_foot').id: k for k, leg in enumerate(LEGS)}
        self._leg_of_geom = np.full(m.ngeom, -1)          # geom id -> leg index of a foot, -1 otherwise
        self._leg_of_geom[list(self._foot_geom)] = list(self._foot_geom.values())
        self._foot_tip_site = np.array([m.site(f'leg{leg}_foot_tip').id for leg in LEGS])    # legs 1..6


def dictionary_tables(robot: Robot, terms: np.ndarray, dadr: np.ndarray, fc: np.ndarray, stick: np.ndarray):
    """The compiled loop's tables of the dictionary's terms (:func:`firmware.dictionary_pass`): joints with a
    spring, periodic or load friction, their parameters and friction loss, and the supply sag."""
    on = np.flatnonzero(np.any(terms[:, [T_K, T_PA, T_MU]] != 0, axis=1))
    dint = np.array([on, dadr[on], stick[on].astype(np.int64)], dtype=np.int64).reshape(3, -1)
    dflt = np.array([terms[on, T_K], terms[on, T_REST], terms[on, T_PA], terms[on, T_PP], terms[on, T_PPH],
                     terms[on, T_MU], fc[on]], dtype=float).reshape(7, -1)
    s = robot.servo
    supply = np.array([supply_resistance_ohm(robot) / s.supply_voltage_v,
                       1.0 / (s.torque_constant_nm_per_a * s.gear_ratio)])
    return dint, dflt, supply
