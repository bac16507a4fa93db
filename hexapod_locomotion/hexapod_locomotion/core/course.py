"""Following the commanded velocity with odometry: heading and lateral correction. Pure numpy.

Open loop, a velocity command becomes a foothold displacement and a yaw per gait cycle; feet that
slip, a leg that stalls on a block or lands on an edge leave the body off that course, and nothing
on board notices. :class:`CourseKeeper` compares the odometry's pose with the course the command
asks for and adds to the command, once per gait phase:

* heading: the reference heading integrates the commanded yaw rate from where the command began;
  ``heading_gain`` of the difference to the estimated heading is added as yaw rate over one gait cycle,
  and the sum is divided by the share of the placed yaw the gait turns the body
  (:func:`placed_turn_share`), so turning in place follows the commanded rate;
* lateral (only while the command has no yaw rate): the reference line starts at the pose where the
  command began, in the commanded direction of travel; ``lateral_gain`` of the cross-track distance
  is added as sideways velocity over one gait cycle. Progress along the line is not corrected: the
  stride sets the speed. A command faster than the gait walks is first slowed to the gait's speed
  (the controller scales the whole step down to its stride, the sideways part with it: the pentapod,
  12 cm a 5.9 s cycle, asked 0.05 m/s, moved 0.4 of the sideways correction asked for).

Both errors are means over the last gait cycle (the reference's too): a gait sways the body in yaw
and sideways within each cycle as its groups are placed (pentapod on the blocks: +-4 degrees), and
that sway is no drift to correct. The heading error's mean is carried on to now by its trend from
the cycle before (the mean lags by half a cycle: tetrapod on the blocks, seed 0, 40 s, a leg stalled
and the body yawed by 20 degrees; corrected on the mean alone it overshot by 3.4 degrees, by 6.9 at
twice the gain; with the trend it ended 1.6 degrees off).

A new command (a different velocity, or walking again after standing) starts a new reference. While
turning, the reference heading stays within ``max_heading_error_rad`` ahead of the estimate (a
robot that cannot turn as fast as asked is not wound up without end); walking without a yaw rate it
holds, however far the body has yawed (only the correction asked for is limited to that error).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from hexapod_locomotion.core.gait import Gait
from hexapod_locomotion.core.locomotion_params import LocomotionError, VelocityCommand
from hexapod_locomotion.core.odometry import wrap_angle
from hexapod_model.param_schema import param


@dataclass(frozen=True)
class CourseChoice:
    """Whether the walk follows the command with the odometry: locomotion_node's parameter and a
    trial's field (declared once here; the trials default to the paper's open loop)."""

    heading_correction: bool = param(True, 'follow /cmd_vel with the odometry (and /imu when it is published): '
                                     'correct the heading towards the commanded yaw rate and the sideways drift off '
                                     "the commanded line; false = the paper's open loop (the command as it is)")


@dataclass(frozen=True)
class CourseConfig:
    heading_gain: float = 0.5          # fraction of the heading error removed per gait cycle
    lateral_gain: float = 0.5          # fraction of the cross-track error removed per gait cycle
    max_heading_error_rad: float = 0.3
    max_lateral_mps: float = 0.02      # largest sideways correction [m/s]
    restart_after_s: float = 1.0       # a gap this long between commands starts a new reference
    trend: float = 1.0                 # share of the heading error's trend (last two cycles) carried on to now

    def __post_init__(self):
        for name in self.__dataclass_fields__:
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
                raise LocomotionError(f'course correction {name} must be a finite number >= 0, got {v!r}')


def placed_turn_share(n_phases: int) -> float:
    """Of the yaw per cycle the controller places the feet for, the share the body turns: n / (n + 1)
    for a gait of ``n`` equal groups.

    Each swing places its feet at the neutral foothold turned by half the cycle's yaw (as the stride,
    half ahead), and the leveling then turns the body by the mean angle of all six feet off their
    neutral footholds (:meth:`GaitController._level_target`), which it leaves at zero. In the steady
    turn, with the body turning by r per phase, a foot sits yaw/2 - k r off neutral k phases after it
    landed (k = 1..n); their mean is zero when r = yaw / (n + 1), so the body turns n / (n + 1) of the
    yaw per cycle (tripod 2/3, tetrapod 3/4, pentapod 6/7; measured open loop, turning in place on flat
    ground at 0.05 rad/s for 30 s, the first cycle included: tripod 0.62, tetrapod 0.72)."""
    return n_phases / (n_phases + 1.0)


@dataclass
class CourseKeeper:
    """``turn_share``: :func:`placed_turn_share` of the gait walked; the yaw rate asked of the controller
    is divided by it, so the body turns at the rate the course needs."""

    config: CourseConfig = CourseConfig()
    turn_share: float = 1.0

    @classmethod
    def for_gait(cls, gait: Gait, config: CourseConfig = CourseConfig()) -> CourseKeeper:
        """The keeper of a walk in ``gait``: every walker (locomotion_node, the trial runner) builds it here."""
        return cls(config, turn_share=placed_turn_share(gait.n_phases))

    def __post_init__(self):
        if not (math.isfinite(self.turn_share) and 0.0 < self.turn_share <= 1.0):
            raise LocomotionError(f'course correction turn_share must be in (0, 1], got {self.turn_share!r}')
        self._cmd: VelocityCommand | None = None
        self._t: float | None = None
        self.yaw_ref = 0.0
        self.anchor = np.zeros(2)

    def _start(self, t_s: float, cmd: VelocityCommand, xy, yaw: float) -> None:
        self._cmd, self._t = cmd, t_s
        self.yaw_ref = yaw
        self.anchor = np.array(xy, dtype=float)
        self._hist: list[tuple[float, float, float, np.ndarray]] = []    # (t, yaw, yaw_ref unwrapped, xy)

    def errors(self, xy, yaw: float) -> tuple[float, float]:
        """(heading error [rad], cross-track error [m], left of the line positive) of a pose."""
        cmd = self._cmd
        e_yaw = wrap_angle(self.yaw_ref - yaw)
        if cmd is None or cmd.wz != 0.0 or (cmd.vx == 0.0 and cmd.vy == 0.0):
            return e_yaw, 0.0
        phi = self.yaw_ref + math.atan2(cmd.vy, cmd.vx)
        d = np.asarray(xy, dtype=float) - self.anchor
        return e_yaw, float(-math.sin(phi) * d[0] + math.cos(phi) * d[1])

    def _heading_error(self, last, t_s: float) -> float:
        """The heading error now: its mean over the last cycle, carried on to now by its trend from the
        cycle before (``trend`` of it; the mean lags by about half a cycle, and a correction acting on
        that late overshoots)."""
        def mean_error(window) -> tuple[float, float]:
            """(mean heading error, mean time) of a window of the history."""
            return float(np.mean([h[2] - h[1] for h in window])), float(np.mean([h[0] for h in window]))
        e_last, t_last = mean_error(last)
        before = self._hist[:len(self._hist) - len(last)]
        if len(before) < max(len(last) - 1, 1):
            return wrap_angle(e_last)
        e_before, t_before = mean_error(before)
        slope = (e_last - e_before) / (t_last - t_before)
        return wrap_angle(e_last + self.config.trend * slope * (t_s - t_last))

    def command(self, t_s: float, cmd: VelocityCommand, xy, yaw: float, cycle_s: float,
                max_speed_mps: float = math.inf) -> VelocityCommand:
        """The command to walk this phase with: ``cmd`` corrected for the pose ``xy``, ``yaw`` (odom);
        ``max_speed_mps``: the fastest the gait walks (its stride per cycle; the command's speed is capped
        at it before the sideways correction is added)."""
        c = self.config
        if self._cmd != cmd or self._t is None or t_s - self._t > c.restart_after_s + cycle_s:
            self._start(t_s, cmd, xy, yaw)
        else:
            self.yaw_ref = wrap_angle(self.yaw_ref + cmd.wz * (t_s - self._t))
            self._t = t_s
            if cmd.wz != 0.0:                  # turning: the line is rebuilt from the pose reached
                self.anchor = np.array(xy, dtype=float)
        if self._hist:
            _, y0, r0, _ = self._hist[-1]
            yaw_u, ref_u = y0 + wrap_angle(yaw - y0), r0 + wrap_angle(self.yaw_ref - r0)
        else:
            yaw_u, ref_u = yaw, self.yaw_ref
        self._hist = [h for h in self._hist if h[0] > t_s - 2 * cycle_s + 1e-9] + [(t_s, yaw_u, ref_u, np.array(xy, float))]
        last = [h for h in self._hist if h[0] > t_s - cycle_s + 1e-9]
        yaw_m = float(np.mean([h[1] for h in last]))
        _, e_lat = self.errors(np.mean([h[3] for h in last], axis=0), yaw_m)
        e_yaw = self._heading_error(last, t_s)
        lead = wrap_angle(self.yaw_ref - yaw)
        if cmd.wz * lead > 0 and abs(lead) > c.max_heading_error_rad:
            # a turn the body does not keep up with: the reference waits (walking straight, it holds)
            self.yaw_ref = wrap_angle(yaw + math.copysign(c.max_heading_error_rad, lead))
            self._hist[-1] = (t_s, yaw_u, yaw_u + wrap_angle(self.yaw_ref - yaw), self._hist[-1][3])
        if abs(e_yaw) > c.max_heading_error_rad:
            e_yaw = math.copysign(c.max_heading_error_rad, e_yaw)
        wz = (cmd.wz + c.heading_gain * e_yaw / cycle_s) / self.turn_share
        v_lat = float(np.clip(-c.lateral_gain * e_lat / cycle_s, -c.max_lateral_mps, c.max_lateral_mps))
        # the sideways velocity, perpendicular to the line (left positive), in the body frame
        phi = self.yaw_ref + math.atan2(cmd.vy, cmd.vx) if (cmd.vx or cmd.vy) else yaw
        ang = phi + math.pi / 2 - yaw
        speed = math.hypot(cmd.vx, cmd.vy)
        k = min(1.0, max_speed_mps / speed) if speed > 0 else 1.0
        return VelocityCommand(k * cmd.vx + v_lat * math.cos(ang), k * cmd.vy + v_lat * math.sin(ang), wz)
