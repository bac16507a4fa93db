"""The MuJoCo hexapod as a servo bus: AX-12A firmware at 1 kHz, sequential reads, sensors. No rclpy.

:class:`HexapodSim` implements :class:`hexapod_model.bus.ServoBus`, so the locomotion library, the
driver's bus emulator and the sim node drive it exactly like the real robot.

Timing (the project convention, all times in seconds of simulated time):

* Physics steps every ``timestep_s`` (default 1 ms, the firmware period); bus times are whole
  physics steps.
* The firmware of every servo runs at integer multiples of ``control_period_s`` (1 ms). At a tick
  it reads the integer present tick (the output shaft position, quantised) and the integer goal,
  and outputs :func:`hexapod_model.servo.firmware_torque_nm` (tabulated per servo for every
  possible integer error); the torque is held until the next tick. The loop over firmware ticks
  and physics steps is compiled (:mod:`hexapod_sim.physics.firmware`, numba).
* :meth:`sync_write` is one transaction at the current time (duration ``t_write_s``, 0 by default,
  as in Algorithm 1 where only reads cost time); a goal written at ``t`` takes effect at the first
  firmware tick at or after ``t``.
* :meth:`read_position` samples the position at the start of the transaction, then the bus is busy
  for ``t_com_s``; reads are sequential. The value is the integer tick the servo reports,
  converted back to the DH angle with the joint's bus direction/offset.

Effects of the robot description are emulated in the tables the plant is built with
(:mod:`hexapod_sim.physics.plant_tables`, which lists them) and in the MJCF (:mod:`hexapod_sim.physics.mjcf`);
their values never leave this class except as physics.

Sensors: body IMU (orientation, linear acceleration, angular rate) at ``imu_rate_hz`` with exact
stamps (a sample between two physics steps is interpolated linearly between them, the quaternion
normalised); battery (supply voltage x current, from
:func:`hexapod_model.servo.electrical_power_w` of every servo plus ``electronics_idle_power_w``);
servo temperatures (first-order thermal model driven by :func:`hexapod_model.servo.winding_loss_w`;
a servo above ``shutdown_temperature_c`` turns its torque off and flags overheating, like the
AX-12A alarm shutdown); evaluation-only truth (foot contacts and forces, body pose).
"""
from __future__ import annotations

import math
from collections import deque
from typing import Callable, Iterable, Mapping

import mujoco
import numpy as np

from hexapod_model.bus import ServoBus, SimulatedServos
from hexapod_model.description import ALL_JOINTS, LEGS, Robot, load_robot
from hexapod_model.imu import ImuReading
from hexapod_model.servo import (
    ERR_ANGLE_LIMIT,
    ERR_OVERHEATING,
    electrical_power_w,
    winding_loss_w,
)
from hexapod_sim.physics import firmware
from hexapod_sim.physics.mjcf import TIMESTEP_S, Scene
from hexapod_sim.physics.mjcf import scene as build_scene
from hexapod_sim.physics.plant_tables import POWER_WINDOW, PlantTables
from hexapod_sim.physics.readings import BatteryReading, FootContacts, ServoTelemetry, rotate_to_body
from hexapod_sim.physics.terrain import Terrain

DEFAULT_AMBIENT_C = 22.0      # [P] Sec. 8.4 room temperature
DEFAULT_START_TEMPERATURE_C = 37.0   # [P] Sec. 8.4 servo temperature of the standing robot
IMU_BUFFER = 4096             # IMU samples kept for pop_imu_samples()


class SimError(ValueError):
    """Bad input to the simulator (the message names the offending value)."""


class HexapodSim(ServoBus, SimulatedServos, PlantTables):
    """MuJoCo hexapod + AX-12A firmware + bus timing. See the module docstring for the conventions.

    ``robot``: the description (default :func:`load_robot`); ``terrain``: a name of
    :data:`hexapod_sim.physics.terrain.TERRAINS` or a :class:`Terrain`; ``seed``: for random terrains;
    ``t_com_s``: duration of one read (default ``robot.bus.t_com_s``; 0.016 for a stock USB
    adapter); ``fixed_base``: trunk welded in the air, no ground (calibration stand, free swing);
    ``timestep_s``: physics step (divides the 1 ms firmware period); ``t_write_s``: duration of a
    sync write; ``imu_rate_hz``: IMU sample rate (samples between physics steps are interpolated
    linearly, the quaternion normalised); ``ambient_c``/``initial_temperature_c``: thermal model;
    ``start_xy_m``: where the robot stands at the ``home`` keyframe.
    """

    def __init__(self, robot: Robot | None = None, terrain: str | Terrain = 'flat', seed: int = 0,
                 t_com_s: float | None = None, fixed_base: bool = False, timestep_s: float = TIMESTEP_S,
                 t_write_s: float = 0.0, imu_rate_hz: float = 400.0, ambient_c: float = DEFAULT_AMBIENT_C,
                 initial_temperature_c: float = DEFAULT_START_TEMPERATURE_C,
                 start_xy_m: tuple[float, float] = (0.0, 0.0)):
        self.robot = robot if robot is not None else load_robot()
        try:
            self.scene: Scene = build_scene(self.robot, terrain, seed=seed, fixed_base=fixed_base,
                                            timestep_s=timestep_s, start_xy_m=start_xy_m)
        except ValueError as exc:
            raise SimError(str(exc)) from None
        self.model = mujoco.MjModel.from_xml_string(self.scene.xml)
        self.data = mujoco.MjData(self.model)
        self.dt = float(self.model.opt.timestep)
        s = self.robot.servo
        self._servo = s
        self._spm = int(round(s.control_period_s / self.dt))          # physics steps per firmware tick
        self.t_com_s = float(self.robot.bus.t_com_s if t_com_s is None else t_com_s)
        self._com_steps = self._steps_of(self.t_com_s, 't_com_s', positive=True)
        self.t_write_s = float(t_write_s)
        self._write_steps = self._steps_of(self.t_write_s, 't_write_s', positive=False)
        if not math.isfinite(imu_rate_hz) or not 0 <= imu_rate_hz <= 1.0 / self.dt + 1e-9:
            raise SimError(f'imu_rate_hz must be in 0..{1.0 / self.dt:g} (0 = no IMU; at most one sample per '
                           f'physics step), got {imu_rate_hz!r}')
        self._imu_period_steps = (1.0 / imu_rate_hz) / self.dt if imu_rate_hz else 0.0
        for name, v in (('ambient_c', ambient_c), ('initial_temperature_c', initial_temperature_c)):
            if not math.isfinite(v) or not -40.0 <= v <= 120.0:
                raise SimError(f'{name} must be a temperature in -40..120 C, got {v!r}')
        self.ambient_c = float(ambient_c)
        self.initial_temperature_c = float(initial_temperature_c)
        self._build_tables()
        self.reset()

    # ------------------------------------------------------------------ set-up helpers
    def _steps_of(self, t: float, what: str, positive: bool) -> int:
        if not math.isfinite(t) or t < 0 or (positive and t <= 0):
            raise SimError(f'{what} must be a {"positive" if positive else "non-negative"} time in seconds, got {t!r}')
        k = t / self.dt
        if abs(k - round(k)) > 1e-6:
            raise SimError(f'{what}={t} s is not a whole number of physics steps ({self.dt} s)')
        return int(round(k))

    def reset(self, keyframe: str = 'home', joint_angles: Mapping[str, float] | None = None) -> None:
        """Restart at ``keyframe`` (optionally with some joints moved), time 0, servos holding the pose.

        The goals are set to the (quantised) starting angles, temperatures to the initial value,
        torque enabled on every servo, the energy counter to zero.
        """
        m, d = self.model, self.data
        try:
            key = m.keyframe(keyframe).id
        except KeyError:
            raise SimError(f'unknown keyframe {keyframe!r}') from None
        mujoco.mj_resetDataKeyframe(m, d, key)
        if joint_angles:
            for name, v in joint_angles.items():
                i = self._joint_index(name)
                if not math.isfinite(float(v)):
                    raise SimError(f'{name}: starting angle must be finite, got {v!r}')
                d.qpos[self._qadr[i]] = float(v)
        mujoco.mj_forward(m, d)
        n = len(ALL_JOINTS)
        self._st[:] = 0                                # step 0, first firmware tick at step 0
        self._rows = np.arange(n)                      # torque-table row per servo (n = torque off)
        self._jint[firmware.J_ROW_OFF] = self._rows * self._table_width
        self._error_bits = np.zeros(n, dtype=np.int64)
        self._goal = np.zeros(n, dtype=np.int64)
        self._write_keys, self._write_idx = None, None  # joints of the last sync write and their indices
        self._pending: list[tuple[int, int, np.ndarray, np.ndarray]] = []   # (step, seq, idx, angles) not yet acting
        self._set_goal_ticks(np.arange(n), self._quantize_n(self._output_q() * self._tick_scale + self._tick_base))
        self._tau[:] = 0.0
        self._power_w = self.robot.electronics_idle_power_w
        self._energy_j = 0.0
        self._temp = np.full(n, self.initial_temperature_c)
        self._imu = deque(maxlen=IMU_BUFFER)
        self._last_imu = None
        self._imu_k = 0                                # next IMU sample index (time k / rate)
        self._imu_carry = None                         # last sensor row of the previous drain
        self.bus_stats = {'reads': 0, 'writes': 0}
        if self._stick_idx.size:
            m.dof_frictionloss[self._stick_dadr] = self._fric_static
            self._stick_flt[2] = 0.0
            self._stick_flt[3] = 1.0
        self._hist[:] = self._output_q()
        d.ctrl[:] = 0.0

    def _joint_index(self, name: str) -> int:
        try:
            return self._index[name]
        except (KeyError, TypeError):
            raise SimError(f'unknown joint {name!r}; joints are leg<1..6>_<coxa|femur|tibia>') from None

    # ------------------------------------------------------------------ physics loop
    @property
    def _step(self) -> int:
        return int(self._st[firmware.ST_STEP])

    def _output_q(self) -> np.ndarray:
        """Output-shaft angle of every servo (motor hinge plus backlash play); a new array."""
        q = self.data.qpos[self._qadr]
        has_play = self._play_qadr >= 0
        if has_play.any():
            q[has_play] += self.data.qpos[self._play_qadr[has_play]]
        return q

    def _set_goal_ticks(self, idx, ticks) -> None:
        self._goal[idx] = ticks
        self._jint[firmware.J_GOAL_IDX] = self._goal + self._err_off   # table index: goal - present + max_tick

    def _quantize_n(self, raw_tick: np.ndarray) -> np.ndarray:
        """:func:`hexapod_model.servo.quantize_tick` as the compiled loop does it (a test checks both)."""
        return firmware.quantize_array(np.ascontiguousarray(raw_tick, dtype=float), float(self._servo.max_tick))

    def _window_state(self) -> tuple[float, float, np.ndarray]:
        """(energy [J], power at the last tick [W], temperatures) including the ticks still buffered.

        Pure: the committed state only changes at full windows, so asking for sensor values never
        changes a run (bit for bit).
        """
        k = int(self._st[firmware.ST_WIN_N])
        if k == 0:
            return self._energy_j, self._power_w, self._temp
        s = self._servo
        tau, omega = self._win_tau[:k], self._win_omega[:k]
        p = np.sum(electrical_power_w(tau, omega, s), axis=1) + self.robot.electronics_idle_power_w
        t_inf = self.ambient_c + winding_loss_w(tau, omega, s) * s.thermal_resistance_k_per_w
        carry, weights = self._therm_w[k]
        return (self._energy_j + float(np.sum(p)) * s.control_period_s, float(p[-1]),
                carry * self._temp + weights @ t_inf)

    def _flush_power(self) -> None:
        """Commit a full window of firmware ticks to the battery and thermal state (exact per tick)."""
        self._energy_j, self._power_w, self._temp = self._window_state()
        self._st[firmware.ST_WIN_N] = 0
        s = self._servo
        hot = self._temp > s.shutdown_temperature_c
        if hot.any():                       # AX-12A alarm shutdown: torque off, overheating bit
            self._rows = np.where(hot, len(ALL_JOINTS), self._rows)
            self._jint[firmware.J_ROW_OFF] = self._rows * self._table_width
        self._error_bits = np.where(hot, self._error_bits | ERR_OVERHEATING, self._error_bits & ~ERR_OVERHEATING)

    def _advance_to_step(self, target: int) -> None:
        while self._pending and self._pending[0][0] <= target:
            at, _seq, idx, vals = self._pending.pop(0)
            self._run_to_step(at)
            self._write_goal_ticks(idx, vals)
        self._run_to_step(target)

    def _run_to_step(self, target: int) -> None:
        st = self._st
        while st[0] < target:                          # st[firmware.ST_STEP]
            firmware.run(target, *self._loop_args)
            if st[firmware.ST_WIN_N] == POWER_WINDOW:
                self._flush_power()
            if self._sens_buf.shape[0] and st[firmware.ST_SENS_N] == self._sens_buf.shape[0]:
                self._drain_sensors()

    def _imu_rows(self, raw: np.ndarray) -> np.ndarray:
        """Loop rows (quat, world linear acceleration, body angular velocity) -> IMU readings
        (quat, specific force in the body frame = R^T (a - g), angular velocity)."""
        out = raw.copy()
        if self.scene.fixed_base:                    # welded: constant pose, at rest
            out[:, :4] = self.data.xquat[self._trunk]
            out[:, 7:10] = 0.0
            out[:, 4:7] = 0.0
        out[:, 4:7] = rotate_to_body(out[:, :4], out[:, 4:7] - self.model.opt.gravity)
        return out

    def _drain_sensors(self, min_samples: int = 1) -> None:
        """Turn the buffered per-step sensor rows into IMU samples at exact multiples of the IMU period
        (only once ``min_samples`` are complete, unless the buffer is half full)."""
        n = int(self._st[firmware.ST_SENS_N])
        if n == 0:
            return
        P = self._imu_period_steps
        # the buffer holds sensor rows up to step now - 1; sample k needs the row at ceil(k P)
        if (int(self._st[firmware.ST_STEP]) - 1 < math.ceil((self._imu_k + min_samples - 1) * P - 1e-9)
                and n < self._sens_buf.shape[0] // 2):
            return                                     # not enough complete samples yet: keep buffering
        steps, rows = self._sens_step[:n], self._imu_rows(self._sens_buf[:n])
        if self._imu_carry is not None:
            steps = np.concatenate([[self._imu_carry[0]], steps])
            rows = np.vstack([self._imu_carry[1], rows])
        self._st[firmware.ST_SENS_N] = 0
        P = self._imu_period_steps
        first, last = int(steps[0]), int(steps[-1])
        # samples whose bracketing steps are all available: x_k = k P <= last
        k_end = int(math.floor(last / P + 1e-9)) + 1
        ks = np.arange(self._imu_k, k_end)
        if ks.size:
            x = ks * P
            lo = np.floor(x + 1e-9).astype(np.int64)
            f = np.clip(x - lo, 0.0, 1.0)
            f[f < 1e-9] = 0.0
            hi = np.minimum(lo + 1, last)
            a, b = rows[lo - first], rows[hi - first]
            v = (1 - f)[:, None] * a + f[:, None] * b
            flip = np.sum(a[:, :4] * b[:, :4], axis=1) < 0          # blend quaternions in one hemisphere
            v[flip, :4] = (1 - f[flip])[:, None] * a[flip, :4] - f[flip][:, None] * b[flip, :4]
            norm = np.linalg.norm(v[:, :4], axis=1)
            v[:, :4] /= np.where(norm > 0, norm, 1.0)[:, None]
            for t, row in zip((x * self.dt).tolist(), v):   # rows of a fresh array: views are safe
                self._imu.append(ImuReading(t, row[:4], row[4:7], row[7:10]))
            self._last_imu = self._imu[-1]
            self._imu_k = int(k_end)
        self._imu_carry = (last, rows[-1].copy())

    def step(self, duration_s: float) -> float:
        """Advance the simulation by ``duration_s`` (rounded up to whole physics steps); returns now()."""
        if not math.isfinite(duration_s) or duration_s < 0:
            raise SimError(f'duration_s must be a non-negative number, got {duration_s!r}')
        self._advance_to_step(self._step + int(math.ceil(duration_s / self.dt - 1e-9)))
        return self.now()

    # ------------------------------------------------------------------ ServoBus protocol
    def now(self) -> float:
        """Current simulated time [s]."""
        return self._step * self.dt

    def sync_write(self, goals_rad: Mapping[str, float]) -> float:
        """Write goal angles (joint -> theta [rad]) to their servos in one transaction; returns its time.

        Unknown joints and non-finite angles raise :class:`SimError` and nothing is written. Goals
        outside the joint limits are clamped to them and flag the servo's angle-limit error bit
        (as the AX-12A's CW/CCW angle limits do) until an in-range goal is written.
        """
        try:
            items = goals_rad.items()
        except AttributeError:
            raise SimError('goals must be a mapping joint name -> angle [rad], '
                           f'got {type(goals_rad).__name__}') from None
        keys = tuple(goals_rad)
        if keys == self._write_keys:                   # the same joints as the last write (the usual case)
            idx = self._write_idx
        else:
            index = self._index
            try:
                idx = np.fromiter((index[k] for k in keys), dtype=np.int64, count=len(keys))
            except (KeyError, TypeError):
                bad = next(k for k in keys if k not in index)
                raise SimError(f'unknown joint {bad!r}; joints are leg<1..6>_<coxa|femur|tibia>') from None
        try:
            vals = np.fromiter(goals_rad.values(), dtype=float, count=len(keys))
        except (TypeError, ValueError):
            bad = next((k, v) for k, v in items if not isinstance(v, (int, float, np.number)))
            raise SimError(f'{bad[0]}: goal must be a number, got {bad[1]!r}') from None
        lag = self._goal_lag[idx]
        if lag.any():                                  # a goal latency: the goals act later (checked now)
            finite = np.isfinite(vals)
            if not finite.all():
                bad = int(np.argmin(finite))
                raise SimError(f'{ALL_JOINTS[idx[bad]]}: goal must be finite, got {vals[bad]!r}')
            for lg in np.unique(lag):
                sel = lag == lg
                self._pending.append((self._step + int(lg), self.bus_stats['writes'], idx[sel], vals[sel]))
            self._pending.sort(key=lambda x: (x[0], x[1]))
            if self._pending[0][0] <= self._step:
                self._advance_to_step(self._step)
        else:
            self._write_goal_ticks(idx, vals)
        self._write_keys, self._write_idx = keys, idx
        t = self.now()
        self.bus_stats['writes'] += 1
        if self._write_steps:
            self._advance_to_step(self._step + self._write_steps)
        return t

    def _write_goal_ticks(self, idx: np.ndarray, vals: np.ndarray) -> None:
        bad = firmware.write_goals(idx, vals, self._lim_lo, self._lim_hi, self._tick_scale, self._tick_base,
                                   float(self._servo.max_tick), ERR_ANGLE_LIMIT, self._error_bits, self._goal,
                                   self._jint)
        if bad >= 0:
            raise SimError(f'{ALL_JOINTS[idx[bad]]}: goal must be finite, got {vals[bad]!r}')

    def read_position(self, joint: str) -> tuple[float, float]:
        """Read one servo: (theta [rad] of the reported integer tick, sample time [s]). Costs ``t_com_s``."""
        theta, stamp = self.sample_position(joint)
        self.bus_stats['reads'] += 1
        self._advance_to_step(int(self._st[0]) + self._com_steps)
        return theta, stamp

    def sample_position(self, joint: str) -> tuple[float, float]:
        """What a read of ``joint`` reports now, without the bus time a read costs: (theta [rad] of the
        reported integer tick, sample time [s]). For a bus whose time is kept by someone else (the
        bus emulator keeps the physics on the wall clock; the pseudo-terminal's own round trip is
        the read's cost there)."""
        i = self._index.get(joint)
        if i is None:
            self._joint_index(joint)                         # raises the named error
        s = int(self._st[0])                                  # firmware.ST_STEP
        scale, base, qadr, play, delay = self._read_consts[i]
        if delay:
            q = float(self._hist[max(s - delay, 0) % len(self._hist), i])   # step 0 holds the start pose
        else:
            q = float(self._qpos[qadr])
            if play >= 0:
                q += float(self._qpos[play])
        # quantize_tick for one value (round half to even, clip), in Python floats
        tick = min(max(round(q * scale + base), 0), self._max_tick)
        return (tick - base) / scale, s * self.dt

    def wait_until(self, t: float) -> None:
        """Let the bus idle until ``t`` (rounded up to the physics grid); no-op if already past."""
        if not math.isfinite(t):
            raise SimError(f'wait_until: time must be finite, got {t!r}')
        target = int(math.ceil(t / self.dt - 1e-9))
        if target > self._step:
            self._advance_to_step(target)

    def set_joint_state(self, angles_rad: Mapping[str, float], velocities_rad_s: Mapping[str, float]) -> None:
        """Move joints to ``angles_rad`` with ``velocities_rad_s`` now, time and goals unchanged (a replay
        that restarts a leg from a recorded state; on a welded base the legs do not touch each other)."""
        m, d = self.model, self.data
        for name, v in angles_rad.items():
            i = self._joint_index(name)
            w = float(velocities_rad_s.get(name, 0.0))
            if not (math.isfinite(float(v)) and math.isfinite(w)):
                raise SimError(f'{name}: state must be finite, got {v!r}, {w!r}')
            d.qpos[self._qadr[i]] = float(v)
            d.qvel[self._dadr[i]] = w
        mujoco.mj_forward(m, d)

    def joint_position_index(self, joint: str) -> int:
        """Index of ``joint``'s angle in ``data.qpos`` (its output angle: without backlash play)."""
        return int(self._qadr[self._joint_index(joint)])

    def set_gravity(self, gravity_m_s2) -> None:
        """Gravity in world coordinates from now on [m/s^2]. On a welded base, gravity minus the trunk's
        acceleration (both in the trunk's frame) replays a moving body's legs as they would move on it."""
        g = np.asarray(gravity_m_s2, dtype=float)
        if g.shape != (3,) or not np.all(np.isfinite(g)):
            raise SimError(f'gravity must be 3 finite numbers, got {gravity_m_s2!r}')
        self.model.opt.gravity[:] = g

    # ------------------------------------------------------------------ torque
    def set_torque_enabled(self, enabled: bool, joints: Iterable[str] | None = None) -> None:
        """Torque on/off (Torque Enable register) for ``joints`` (default all). Re-enabling clears a shutdown."""
        idx = np.arange(len(ALL_JOINTS)) if joints is None else np.array([self._joint_index(j) for j in joints])
        self._rows = self._rows.copy()
        self._rows[idx] = idx if enabled else len(ALL_JOINTS)
        self._jint[firmware.J_ROW_OFF] = self._rows * self._table_width

    def emergency_stop(self) -> None:
        """Torque off on every servo (stays off until :meth:`set_torque_enabled` or :meth:`reset`)."""
        self.set_torque_enabled(False)

    @property
    def torque_enabled(self) -> np.ndarray:
        return self._rows < len(ALL_JOINTS)

    @property
    def writes_act_when_written(self) -> bool:
        """Whether a goal write acts at the step it is written and takes no time: no goal latency
        configured or pending, no write time (what :func:`~.write_schedule.replay_writes` needs)."""
        return not self._goal_lag.any() and not self._write_steps and not self._pending

    # ------------------------------------------------------------------ sensors
    def imu(self) -> ImuReading | None:
        """The latest IMU sample (None before the first one)."""
        self._drain_sensors()
        return self._last_imu

    def pop_imu_samples(self, min_batch: int = 1) -> list[ImuReading]:
        """All IMU samples complete so far and not yet returned (at most the last ``IMU_BUFFER``),
        oldest first. With ``min_batch`` > 1 nothing is returned until that many are complete (cheaper
        when called very often; the samples keep their exact stamps)."""
        self._drain_sensors(min_batch)
        out = list(self._imu)
        self._imu.clear()
        return out

    def battery(self) -> BatteryReading:
        energy, power, _ = self._window_state()
        v = self.robot.servo.supply_voltage_v
        return BatteryReading(self.now(), v, power / v, power, energy)

    def temperatures_c(self) -> np.ndarray:
        return np.array(self._window_state()[2])

    def servo_state(self) -> ServoTelemetry:
        temp = np.array(self._window_state()[2])
        n = len(ALL_JOINTS)
        load = self._tau * self._dir / self._servo.stall_torque_nm     # in the servo's own direction
        return ServoTelemetry(self.now(), temp, np.full(n, self.robot.servo.supply_voltage_v),
                          load, self._error_bits.copy(), self.torque_enabled)

    @property
    def servo_ids(self) -> np.ndarray:
        return self._servo_ids.copy()

    def goal_ticks(self) -> np.ndarray:
        """Integer goal of every servo (raw servo ticks), as the firmware sees them."""
        return self._goal.copy()

    def applied_torque_nm(self) -> np.ndarray:
        """Joint torque of every servo held over the current firmware period."""
        return self._tau.copy()

    # ------------------------------------------------------------------ evaluation-only truth
    def keep_output_angles(self, n_steps: int) -> np.ndarray:
        """Keep the output angle of every joint at the start of each of the first ``n_steps`` physics steps
        (call it right after :meth:`reset`): row ``k`` of the returned (n_steps, 18) array is what
        :meth:`true_joint_angles` gives at step ``k``, filled in by the compiled loop as the sim runs (the
        readout-delay history made that long, so one :meth:`step` over many physics steps records them all).
        Reads and the physics are unchanged."""
        if self._step != 0:
            raise SimError('keep_output_angles: call it right after reset()')
        k = next(i for i, a in enumerate(self._loop_args) if a is self._hist)
        hist = np.empty((max(int(n_steps), self._hist.shape[0]), len(ALL_JOINTS)))
        hist[:] = self._output_q()
        self._hist = hist
        self._loop_args = self._loop_args[:k] + (hist,) + self._loop_args[k + 1:]
        return hist[:int(n_steps)]

    def true_joint_angles(self) -> np.ndarray:
        """Continuous output angles of all joints (truth; the bus reports quantised ticks)."""
        return self._output_q()

    def refresh_derived(self) -> None:
        """Recompute positions, contacts and forces for the current state (after a step MuJoCo holds
        them for the state one step earlier). Does not change the trajectory: the state and the
        solver's warm start are left alone."""
        mujoco.mj_forward(self.model, self.data)

    def body_pose(self) -> tuple[np.ndarray, np.ndarray]:
        """Trunk position [m] and orientation quaternion (w, x, y, z) in the world frame."""
        if self._free_qadr is None:
            return self.data.xpos[self._trunk].copy(), self.data.xquat[self._trunk].copy()
        a = self._free_qadr
        return self.data.qpos[a:a + 3].copy(), self.data.qpos[a + 3:a + 7].copy()

    def foot_contacts(self) -> FootContacts:
        """Which feet touch the terrain and the total contact force on each foot (world frame)."""
        m, d = self.model, self.data
        self.refresh_derived()
        force = np.zeros((len(LEGS), 3))
        touch = np.zeros(len(LEGS), dtype=bool)
        f6 = np.zeros(6)
        for c in range(d.ncon):
            con = d.contact[c]
            g1, g2 = int(con.geom1), int(con.geom2)
            k = self._foot_geom.get(g2, self._foot_geom.get(g1))
            if k is None or con.exclude != 0:
                continue
            mujoco.mj_contactForce(m, d, c, f6)
            fw = con.frame.reshape(3, 3).T @ f6[:3]     # force of geom1 on geom2, world frame
            force[k] += fw if g2 in self._foot_geom else -fw
            touch[k] = True
        return FootContacts(self.now(), touch, force)

    def feet_touching_last_step(self) -> np.ndarray:
        """(6,) bool: the feet in contact in the physics step that just ran: the contacts MuJoCo
        found at its start, i.e. :meth:`foot_contacts`' ``in_contact`` one step (1 ms) earlier, at
        no cost (no collision pass, no forces): what a benchmark's per-millisecond truth takes while
        the robot runs in real time, where a collision pass per sample lengthened the emulated
        servos' replies. Leaves the state alone."""
        d = self.data
        touch = np.zeros(len(LEGS), dtype=bool)
        n = d.ncon
        if n:
            g1, g2 = d.contact.geom1[:n], d.contact.geom2[:n]
            leg = np.where(self._leg_of_geom[g2] >= 0, self._leg_of_geom[g2], self._leg_of_geom[g1])
            touch[leg[(leg >= 0) & (d.contact.exclude[:n] == 0)]] = True
        return touch

    def foot_positions(self) -> np.ndarray:
        """Foot-tip positions (6, 3) in the world frame (truth)."""
        mujoco.mj_kinematics(self.model, self.data)
        return self.feet_at_last_step()

    def feet_at_last_step(self) -> np.ndarray:
        """The foot tips (6, 3, world) as the physics step that just ran found them at its start, at no cost
        (no kinematics pass): :meth:`foot_positions` one step earlier, as :meth:`feet_touching_last_step`."""
        return self.data.site_xpos[self._foot_tip_site].copy()

    def warnings(self) -> dict[str, int]:
        """MuJoCo warning counters that fired since the last reset (empty = healthy)."""
        out = {}
        for i, w in enumerate(self.data.warning):
            if w.number:
                out[mujoco.mjtWarning(i).name] = int(w.number)
        return out


class PowerMeter:
    """The battery as a sampled power sensor reports it: voltage, and current and power averaged
    over the period since the previous sample (energy drawn / time), so the mean of the samples
    over any stretch of samples is the true mean power of that stretch. The sim node's /power and
    the demo's recording both sample through it."""

    def __init__(self, sim: HexapodSim):
        self.sim = sim
        self._last = (sim.now(), sim.battery().energy_j)

    def sample(self) -> BatteryReading:
        b = self.sim.battery()
        t0, e0 = self._last
        p = (b.energy_j - e0) / (b.t_s - t0) if b.t_s > t0 else b.power_w
        self._last = (b.t_s, b.energy_j)
        return BatteryReading(b.t_s, b.voltage_v, p / b.voltage_v, p, b.energy_j)


def run_trajectory(sim: HexapodSim, goals_at: Callable[[float], Mapping[str, float]], duration_s: float,
                   period_s: float = 0.01, on_period: Callable[[HexapodSim], None] | None = None) -> None:
    """Drive ``sim`` with a goal function of time: sync-write ``goals_at(t)`` every ``period_s``.

    ``on_period(sim)`` is called after each period (e.g. to grab a video frame).
    """
    if period_s <= 0 or duration_s < 0:
        raise SimError(f'period_s must be > 0 and duration_s >= 0, got {period_s!r}, {duration_s!r}')
    t_end = sim.now() + duration_s
    while sim.now() < t_end - 1e-12:
        sim.sync_write(goals_at(sim.now()))
        sim.wait_until(min(sim.now() + period_s, t_end))
        if on_period is not None:
            on_period(sim)
