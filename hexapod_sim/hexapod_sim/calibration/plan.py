"""Calibration motion for a robot on a stand (fixed base, feet in the air), for the discrepancy tool.

The routine moves every joint through the conditions in which each candidate effect of
:mod:`hexapod_sim.discrepancy.effects` shows, and reads the moving joints as fast as the bus
allows, so one recording of about a minute lets the tool name what the model leaves out:

========================  ==================================================================
phase                     what it makes observable
========================  ==================================================================
``settle``                start pose, every joint read (initial state of the replay)
``coxa``                  the coxa carries no gravity load: slow and fast triangles (Coulomb
                          friction, viscous damping, readout delay; backlash at every
                          direction reversal), large steps (torque limit), 3-tick steps after
                          holds (break-away friction, compliance dead-band)
``femur``                 the same for the femur under a gravity load that changes with angle
                          (payload), holds high and low
``tibia``                 the tibia swept through vertical, so its gravity load reverses
                          (backlash shows as a jump), steps and small steps
``femur_reversal``        femur swept past vertical with the tibia folded: the femur's gravity
                          load reverses (femur backlash)
``swing``                 swing-down motions as in the paper's Algorithm 1 (femur and tibia
                          together, several durations)
========================  ==================================================================

Every leg runs the same pattern at the same time; on a stand the legs do not interact. Each
control cycle writes the goals of all planned joints in one sync write and then reads the
joints of the current phase one after the other (each read costs ``T_com``), so in the coxa,
femur and tibia phases each read joint is sampled every ``6 T_com``.

:func:`calibration_plan` builds the plan (pure data), :func:`run_calibration` executes it on any
:class:`~hexapod_model.bus.ServoBus` (the MuJoCo sim with ``fixed_base=True``, the emulator or
the real robot through the driver) and returns the :class:`~.discrepancy.recording.Recording`.
See docs/discrepancy.md for recording a real robot.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from hexapod_model.description import JOINT_ROLES, LEGS, Robot, joint_name

PHASES = ('settle', 'coxa', 'femur', 'tibia', 'femur_reversal', 'swing')

# Poses (coxa, femur, tibia) [rad] used by the phases. The tibia hangs vertically at
# theta_3 = -pi/2 - theta_off_2 - theta_off_3 - theta_2 (about -0.54 for a level femur).
_HOME = (0.0, 0.3, -0.3)


class CalibrationError(ValueError):
    """Bad calibration request (the message names the offending argument)."""


@dataclass(frozen=True)
class Phase:
    name: str
    t_start_s: float
    t_end_s: float
    read_roles: tuple[str, ...]


@dataclass(frozen=True)
class CalibrationPlan:
    """Goal angles of one leg pattern at 1 ms resolution plus the phases (which joints to read)."""

    legs: tuple[int, ...]
    dt_s: float
    goals_rad: np.ndarray          # (n, 3): coxa, femur, tibia goal at t = k dt (same for every leg)
    phases: tuple[Phase, ...]

    @property
    def duration_s(self) -> float:
        return (len(self.goals_rad) - 1) * self.dt_s

    def goal_at(self, t_s: float) -> np.ndarray:
        k = min(max(int(t_s / self.dt_s + 1e-9), 0), len(self.goals_rad) - 1)
        return self.goals_rad[k]

    def phase_at(self, t_s: float) -> Phase:
        for ph in self.phases:
            if ph.t_start_s <= t_s < ph.t_end_s:
                return ph
        return self.phases[-1]

    def goals_dict(self, t_s: float) -> dict[str, float]:
        g = self.goal_at(t_s)
        return {joint_name(leg, r): float(g[i]) for leg in self.legs for i, r in enumerate(JOINT_ROLES)}

    def read_joints(self, t_s: float) -> list[str]:
        roles = self.phase_at(t_s).read_roles
        return [joint_name(leg, r) for leg in self.legs for r in JOINT_ROLES if r in roles]


class _Track:
    """Piecewise-linear goal keyframes for (coxa, femur, tibia)."""

    def __init__(self, start):
        self.t = [0.0]
        self.q = [np.array(start, dtype=float)]

    @property
    def now(self) -> float:
        return self.t[-1]

    def hold(self, duration):
        self.t.append(self.now + duration)
        self.q.append(self.q[-1].copy())

    def move(self, target, speed=None, duration=None):
        """Ramp to ``target`` (None keeps a joint) at ``speed`` rad/s of the largest change, or over ``duration``."""
        cur = self.q[-1]
        tgt = np.array([c if v is None else v for c, v in zip(cur, target)], dtype=float)
        dist = float(np.max(np.abs(tgt - cur)))
        if duration is None:
            duration = dist / speed if speed else 0.0
        duration = max(duration, 0.002)
        self.t.append(self.now + duration)
        self.q.append(tgt)

    def step(self, target, hold):
        self.move(target, duration=0.001)
        self.hold(hold)

    def triangle(self, role: int, lo: float, hi: float, speed: float, cycles: int = 1):
        for _ in range(cycles):
            tgt = [None, None, None]
            tgt[role] = hi
            self.move(tgt, speed=speed)
            tgt[role] = lo
            self.move(tgt, speed=speed)

    def sample(self, dt):
        n = int(round(self.now / dt)) + 1
        t = np.arange(n) * dt
        tt = np.array(self.t)
        qq = np.array(self.q)
        return np.stack([np.interp(t, tt, qq[:, i]) for i in range(3)], axis=1)


def _clip_to_limits(robot: Robot, q):
    for i, r in enumerate(JOINT_ROLES):
        lo, hi = robot.joint_limits_rad[r]
        if not lo <= q[i] <= hi:
            raise CalibrationError(f'calibration pose {r}={q[i]:.3f} rad is outside the joint limits [{lo}, {hi}]')


def _check_plan_args(legs, phases, repeats: int, speed_scale: float) -> tuple[int, ...]:
    """:func:`calibration_plan`'s arguments checked; the legs as a tuple of ints."""
    legs = tuple(int(x) for x in legs)
    if not legs or any(leg not in LEGS for leg in legs) or len(set(legs)) != len(legs):
        raise CalibrationError(f'legs must be distinct leg numbers from {LEGS}, got {legs!r}')
    unknown = [p for p in phases if p not in PHASES]
    if unknown:
        raise CalibrationError(f'unknown phase(s) {unknown}; known: {PHASES}')
    if repeats < 1:
        raise CalibrationError(f'repeats must be >= 1, got {repeats}')
    if not speed_scale > 0:
        raise CalibrationError(f'speed_scale must be > 0, got {speed_scale}')
    return legs


def _coxa_motion(tr: _Track, v: float, small: float, vertical: float) -> None:
    """One repetition of the coxa phase (leg stretched out: large inertia)."""
    tr.triangle(0, -0.35, 0.35, 0.35 * v)
    tr.move((0.0, None, None), speed=0.35 * v)
    tr.hold(0.3)
    tr.triangle(0, -0.35, 0.35, 1.4 * v, cycles=2)
    tr.move((0.0, None, None), speed=1.4 * v)
    tr.hold(0.3)
    for target, hold in ((0.3, 0.5), (-0.3, 0.6), (0.1, 0.4), (-0.1, 0.4), (0.0, 0.5)):
        tr.step((target, None, None), hold)
    for target in (small, 0.0, -small, 0.0, 2 * small, 0.0):
        tr.step((target, None, None), 0.35)


def _femur_motion(tr: _Track, v: float, small: float, vertical: float) -> None:
    """One repetition of the femur phase."""
    tr.triangle(1, -0.3, 0.8, 0.4 * v)
    tr.move((None, 0.2, None), speed=0.4 * v)
    tr.hold(0.3)
    tr.triangle(1, -0.3, 0.8, 1.5 * v, cycles=2)
    tr.move((None, 0.2, None), speed=1.5 * v)
    tr.hold(0.3)
    for target, hold in ((0.6, 0.5), (-0.2, 0.6), (0.8, 0.5), (-0.3, 0.5), (0.2, 0.5)):
        tr.step((None, target, None), hold)
    for target in (0.2 + small, 0.2, 0.2 - small, 0.2, 0.2 + 2 * small, 0.2):
        tr.step((None, target, None), 0.35)


def _tibia_motion(tr: _Track, v: float, small: float, vertical: float) -> None:
    """One repetition of the tibia phase, about the tibia hanging straight down (``vertical``)."""
    tr.triangle(2, vertical - 0.45, vertical + 0.6, 0.4 * v)
    tr.move((None, None, vertical + 0.35), speed=0.4 * v)
    tr.hold(0.3)
    tr.triangle(2, vertical - 0.45, vertical + 0.6, 1.5 * v, cycles=2)
    tr.move((None, None, vertical + 0.35), speed=1.5 * v)
    tr.hold(0.3)
    for d, hold in ((-0.35, 0.5), (0.5, 0.5), (-0.2, 0.5), (0.2, 0.5), (0.35, 0.5)):
        tr.step((None, None, vertical + d), hold)
    base = vertical + 0.35
    for target in (base + small, base, base - small, base, base + 2 * small, base):
        tr.step((None, None, target), 0.35)


def _femur_reversal_motion(tr: _Track, v: float, small: float, vertical: float) -> None:
    """One repetition of the femur reversal phase (tibia folded back over the femur)."""
    tr.triangle(1, 1.15, 1.68, 0.3 * v)
    tr.hold(0.3)


def _swing_motion(tr: _Track, v: float, small: float, vertical: float) -> None:
    """One repetition of the swing phase: swing-downs of 0.5, 1.0 and 0.3 s."""
    for t_des in (0.5, 1.0, 0.3):
        tr.move((None, 0.45, 0.1), speed=1.0 * v)
        tr.hold(0.3)
        tr.move((None, -0.15, -0.05), duration=t_des / v)
        tr.hold(0.4)


# per phase after settle: its start pose (given the tibia's vertical angle), the joints it reads and
# one repetition of its motion
_PHASE_MOTIONS = {
    'coxa': (lambda vertical: (0.0, 0.0, 0.6), ('coxa',), _coxa_motion),
    'femur': (lambda vertical: (0.0, 0.2, 0.3), ('femur',), _femur_motion),
    'tibia': (lambda vertical: (0.0, 0.0, vertical + 0.35), ('tibia',), _tibia_motion),
    'femur_reversal': (lambda vertical: (0.0, 1.15, 1.5), ('femur', 'tibia'), _femur_reversal_motion),
    'swing': (lambda vertical: (0.0, 0.45, 0.1), ('femur', 'tibia'), _swing_motion),
}


def _plan_phases(spans, now: float, dt: float) -> tuple[Phase, ...]:
    """The phases from their spans; the transitions between phases belong to the following phase,
    reading its joints, and the last phase ends a control period after ``now``."""
    phases_out = []
    prev_end = 0.0
    for i, (name, a, b, roles) in enumerate(spans):
        start = prev_end if i > 0 else 0.0
        end_t = b if i < len(spans) - 1 else now + dt
        phases_out.append(Phase(name, start, end_t, tuple(roles)))
        prev_end = end_t
    return tuple(phases_out)


def calibration_plan(robot: Robot, legs=LEGS, phases=PHASES, repeats: int = 1, speed_scale: float = 1.0) -> CalibrationPlan:
    """The stand calibration routine for ``legs`` (see the module docstring).

    ``phases``: subset/order of :data:`PHASES` (``settle`` is always first). ``repeats``: how often
    each motion pattern repeats within its phase (more data per condition). ``speed_scale``
    scales every speed (e.g. 0.5 for a gentler first run on a real robot).
    """
    legs = _check_plan_args(legs, phases, repeats, speed_scale)
    v = speed_scale
    s = robot.servo
    small = 3 * s.rad_per_tick             # a 3-tick step: below a strong break-away torque or dead-band
    vertical = -math.pi / 2 - robot.dh['femur'].theta_off_rad - robot.dh['tibia'].theta_off_rad  # tibia straight down
    tr = _Track(_HOME)
    tr.hold(0.6)
    spans: list[tuple[str, float, float, tuple[str, ...]]] = [('settle', 0.0, tr.now, JOINT_ROLES)]
    for name in phases:
        if name == 'settle':
            continue
        pose, roles, motion = _PHASE_MOTIONS[name]
        tr.move(pose(vertical), speed=0.8 * v)
        tr.hold(0.4)
        start = tr.now
        for _ in range(repeats):
            motion(tr, v, small, vertical)
        spans.append((name, start, tr.now, roles))
    tr.move(_HOME, speed=0.8 * v)
    tr.hold(0.3)
    name, a, _, roles = spans[-1]
    spans[-1] = (name, a, tr.now + 1e-9, roles)
    dt = s.control_period_s
    goals = tr.sample(dt)
    for q in (goals.min(axis=0), goals.max(axis=0)):
        _clip_to_limits(robot, q)
    return CalibrationPlan(legs=legs, dt_s=dt, goals_rad=goals, phases=_plan_phases(spans, tr.now, dt))


def run_calibration(bus, plan: CalibrationPlan, progress: bool = True, robot: Robot | None = None):
    """Execute ``plan`` on a :class:`~hexapod_model.bus.ServoBus`; returns the recorded
    :class:`~hexapod_sim.discrepancy.recording.Recording` (every write and read, bus time stamps).

    Each cycle: one sync write of the goals at the current plan time, then the phase's reads one
    after the other. The plan time is the bus time since the start, so a slower bus just gets
    fewer cycles. The write is skipped while no goal changes its integer tick (the firmware only
    sees integer goals, so nothing is lost, and the bus time goes to reads); ``robot`` gives the
    tick size (default: the packaged description).
    """
    from hexapod_model.description import load_robot
    from hexapod_model.servo import theta_to_tick
    from hexapod_sim.discrepancy.recording import Recording
    servo = (robot or load_robot()).servo
    last_ticks = None
    commands, reads = [], []
    t_begin = bus.now()
    bar = None
    if progress:
        from tqdm import tqdm
        bar = tqdm(total=round(plan.duration_s, 1), unit='s', desc='calibration motion', leave=False)
    shown = 0.0
    try:
        while True:
            t = bus.now() - t_begin
            if t > plan.duration_s:
                break
            goals = plan.goals_dict(t)
            ticks = np.rint(theta_to_tick(np.array(list(goals.values())), servo))
            if last_ticks is None or np.any(ticks != last_ticks):
                t_w = bus.sync_write(goals)
                commands.append((t_w, goals))
                last_ticks = ticks
            for j in plan.read_joints(t):
                theta, ts = bus.read_position(j)
                reads.append((ts, j, theta))
            if bar is not None and t - shown >= 0.5:
                bar.update(round(t - shown, 1))
                shown = t
    finally:
        if bar is not None:
            bar.close()
    if not commands or not reads:
        raise CalibrationError('the bus produced no writes or reads (plan duration too short?)')
    t0 = min(commands[0][0], min(r[0] for r in reads))
    t0_ms = math.floor(t0 * 1000.0 + 1e-6)
    t0s = t0_ms / 1000.0
    return Recording.from_samples([(t - t0s, g) for t, g in commands], [(t - t0s, j, v) for t, j, v in reads],
                                  source='calibration', t0_ns=int(t0_ms) * 1_000_000)
