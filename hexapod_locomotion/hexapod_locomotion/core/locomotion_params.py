"""The gait cycle's settings (:class:`LocomotionParams`) and the walking command (:class:`VelocityCommand`)
of :mod:`hexapod_locomotion.core.controller`. Pure Python."""
from __future__ import annotations

import math
from dataclasses import dataclass

from hexapod_locomotion.core.gait import Gait
from hexapod_model.param_schema import ParameterError, param, validate


class LocomotionError(RuntimeError):
    """The controller cannot continue safely (message says why)."""


# Longest duration of a gait-cycle step (t_des_s, swing-up, swing-forward, settle, leveling, dwell) [s].
# The swing-down model and the goal profiles are computed per control period (about 3 ms), so a
# duration far beyond a walk's (the paper: t_des 0.5-1 s) would only exhaust the memory.
MAX_STEP_S = 10.0


def _duration(default: float, description: str, positive: bool = True):
    """A gait-cycle step duration [s]: in (0, MAX_STEP_S], or with ``positive`` False in [0, MAX_STEP_S]."""
    return param(default, description, min=0.0, min_exclusive=positive, max=MAX_STEP_S)


@dataclass(frozen=True)
class LocomotionParams:
    """Gait-cycle parameters. Lengths in metres, times in seconds. Each field is declared once here
    (:func:`hexapod_model.param_schema.param`): locomotion_node's parameter of the same name, its
    parameter file and the trial field (:class:`hexapod_locomotion.trials.trial_runner.TrialConfig`)
    are derived from it; ``exposed=False`` marks the library settings that are neither."""

    t_des_s: float = _duration(1.0, 'swing-down duration [s] (paper: 0.5 or 1 s); shorter is faster but hits '
                               'the ground harder')
    # Transfer phases. With the overlapped transfer (overlap_transfer) the leveling runs beside the next
    # swing-up + swing-forward, so a phase is max(0.3, 0.1 + 0.2) s + settle + swing-down. Measured with
    # table4 on the mockup: with the gaits' strides (9 / 10 / 12 cm) tripod, tetrapod and pentapod at
    # t_des 1 s walk at or above the paper's speeds (in sequence, 0.15 / 0.25 / 0.1 / 0.3 s and 7 cm:
    # 63-77 %). Faster transfers (0.07 / 0.13 / 0.2 s) made the pentapod slower on the blocks (missed
    # contacts, feet on block edges).
    t_swing_up_s: float = _duration(0.1, 'swing-up duration [s]; shorter is faster but jerks the body')
    t_swing_forward_s: float = _duration(0.2, 'swing-forward duration [s]; shorter is faster but the leg may '
                                         'not settle before the swing-down')
    t_level_s: float = _duration(0.3, 'body leveling and forward motion duration [s]; shorter is faster but '
                                 'loads the servos harder')
    # Pause after the swing-forward before the swing-down. The model starts in the leg's motion
    # (start_in_motion), so the legs need not come to rest. Pentapod on the mockup (10 trials
    # of 60 s): 0.1 s walked 0.026 / 0.018 m/s at t_des 0.5 / 1 s, 0.05 s 0.028 / 0.019 (the paper:
    # 0.028 / 0.017); none at all 0.030 / 0.019, but the improved touchdown then missed 1.2 % of its
    # contacts at t_des 1 s (0.2-0.4 % with 0.05 s).
    t_settle_s: float = _duration(0.05, 'pause before the swing-down [s]; too short and a model started at '
                                  'rest (start_in_motion false) mispredicts the start', positive=False)
    write_period_s: float = param(0.01, 'goal update period outside the swing-down [s]', min=0.0,
                                  min_exclusive=True, exposed=False)
    lift_m: float = param(0.05, 'swing-up height above the current foothold [m]', min=0.0)
    max_stride_m: float = param(0.0, "largest foothold displacement per cycle [m]; 0 = the gait's own "
                                '(gaits.yaml: tripod 0.09, tetrapod 0.10, pentapod 0.12); beyond reach is clamped',
                                min=0.0)
    max_turn_rad: float = param(0.0, "largest yaw per cycle [rad]; 0 = the gait's own (gaits.yaml)", min=0.0, exposed=False)
    # theta_fin this far below the nominal ground. Eq. 15 moves the goal from theta_init to theta_fin
    # in t_des, so a deeper theta_fin means a faster swing-down at the same t_des: more free-swing lag
    # (the servo's back-EMF), a higher Eq. 17 threshold and a harder touchdown. 3 cm covers the
    # mockup's step-downs (blocks 0-6 cm: a missed contact is rare and handled); 6 cm raised the
    # peak femur torque at t_des = 0.5 s from 0.66 to 0.89 N m.
    ground_depth_m: float = param(0.03, 'theta_fin this far below the nominal ground [m]; deeper = faster '
                                  'swing-down', min=0.0)
    explicit_forward: float = param(0.8, 'extra body shift per phase, fraction of stride * L / 6', min=0.0,
                                    exposed=False)
    background_reads: bool = param(True, 'read joints round-robin whenever the bus would idle', exposed=False)
    # Leveling treats a leg that has just found ground as carrying this fraction of an equal share
    # of the body weight among the legs that support the next swing (GaitController.
    # landing_preload_rad); 0 = take its goal as it is.
    landing_preload: float = param(1.0, 'a leg that found ground is leveled as carrying this fraction of its '
                                   'share of the weight (compensates servo compliance; 0 = off, for rigid '
                                   'servos)', min=0.0)
    # Touchdown goal profile. 1 = the paper's Eq. 15 (a constant goal rate to theta_fin). Below 1 (the
    # improved touchdown): from approach_height_m above the expected ground (the higher of the nominal
    # ground and the leg's last foothold) the goal moves at this fraction of the Eq. 15 rate, so the
    # free-swing lag - the force with which a foot that has just touched pushes the body up - shrinks
    # by that factor, at the price of a longer swing-down.
    approach_rate: float = param(1.0, "touchdown goal profile: 1 = the paper's Eq. 15 (constant goal rate); "
                                 'below 1 = the improved touchdown, the goal slows to this fraction of the Eq. 15 '
                                 'rate from approach_height_m above the expected ground (less push on the body at '
                                 'contact; a longer swing-down); too small makes walking slow', min=0.0,
                                 min_exclusive=True, max=1.0)
    approach_height_m: float = param(0.015, 'with approach_rate < 1: the slow approach starts this high above '
                                     'the expected ground [m]; too small and contacts meet the fast goal, too '
                                     'large and the swing-down is slow all the way', min=0.0)
    # A leg whose goal has reached theta_fin keeps being read for this long [s] (and still stops on
    # contact) before it stops at theta_fin: a contact late in a slow approach grows its error by a
    # small step per period and can reach theta_fin before it crosses Eq. 17. 0 = Algorithm 1.
    fin_dwell_s: float = _duration(0.0, 'keep reading a leg whose goal reached theta_fin this long [s] before '
                                   'giving up on ground (0 = Algorithm 1); too long delays the next phase when '
                                   'there is no ground', positive=False)
    # Gait-cycle structure. False = the sequence of Fig. 4 as drawn: swing-up, swing-forward,
    # settle, swing-down, then body leveling with every foot down. True = the leveling after a
    # swing-down runs while the next group swings up and forward: the legs that support the next swing
    # level the body and move it forward, the next group lifts its feet from their footholds and
    # carries them forward; the transfer then takes max(t_level_s, t_swing_up_s + t_swing_forward_s)
    # instead of their sum. The swing-down (Algorithm 1) and the leveled pose are unchanged, and the
    # leveling still starts only after every landing leg has stopped (Fig. 4).
    overlap_transfer: bool = param(True, 'gait-cycle structure: true = the body leveling after a swing-down '
                                   'runs while the next group swings up and forward (the phase takes '
                                   'max(t_level_s, t_swing_up_s + t_swing_forward_s) besides settle and '
                                   "swing-down); false = every step in sequence, as drawn in the paper's Fig. 4 "
                                   '(slower)')
    # Where Algorithm 1's model (CalcModel) starts, at the measured theta_init. False = at rest (the
    # paper's robot waited for its legs). True = in the leg's motion: the same leg model, run over the
    # goals written since the swing-up began, gives each leg's (femur, tibia) speed at the swing-down
    # start. A leg still moving there lags differently from one at rest, and a model started at rest
    # stops it in the air. Measured with table4 (10 trials of 60 s per cell): with the 12 cm pentapod
    # stride, 0.1 s of settle leaves the legs moving, 28 / 25 premature stops at t_des 0.5 / 1 s
    # started at rest, 4 / 2 started in motion; without any settle, free swings on flat ground:
    # 34 -> 0 (pentapod, t_des 0.5 s).
    start_in_motion: bool = param(True, "start Algorithm 1's model in the leg's motion at the swing-down start "
                                  "(the leg model run over the transfer's goals); false = at rest, as in the "
                                  'paper (needs a settle long enough for the legs to stop)')
    # The stride grows over the first gait cycle (GaitController.start_ramp); False = full stride from
    # the first phase (a calibration walk's short stride keeps its support without the ramp, and its
    # first swings then carry as much as the later ones).
    start_ramp: bool = param(True, 'grow the stride over the first gait cycle (from the home stance a full '
                             'stride spreads the feet further than any later cycle); false = full stride at once')
    # A swinging leg whose femur or tibia read is further than obstacle_tick from its motion in the air
    # (core.swing_watch) has met an obstacle: its foot is lifted obstacle_lift_m higher for the rest of the
    # swing (over the swing-up time, then on to its foothold at that height). Pushed on instead, a foot
    # held by a block's side lifted the trunk off its stance feet (tripod over the blocks: 1.5 cm, the body
    # turned 12 degrees on two feet). The paper's gait has no such reflex: the trials run without it.
    obstacle_lift_m: float = param(0.03, 'a swinging leg that meets an obstacle (obstacle_tick) is lifted this '
                                   'much higher for the rest of its swing [m]; 0 = off (the paper: the swing '
                                   'goes on into the obstacle)', min=0.0)
    # A leg whose swing-down found no ground hangs over its spot; if the body's centre would then be outside
    # the polygon of the legs left on the ground while the next group swings, the leveling first moves the
    # body this far inside it (GaitController._support_move). The paper's gait lifts the group
    # regardless and the body tips toward the hanging leg. Off by default: at 0.02 m it kept the tetrapod
    # from tipping over the blocks, but on the mockup (its stairs) it cost the tetrapod's CoT 13.8 -> 16.4
    # at t_des 0.5 s and 19.3 -> 27.4 at 1 s (6 trials each, with the course correction and the reflex).
    # Moving the body whenever its centre was less than 2 cm inside (not only outside) moved a pentapod on
    # the mockup 14-16 times a minute, mostly needlessly (CoT at t_des 0.5 s 37.8 against 22.7).
    support_margin_m: float = param(0.0, 'with a leg hanging where it found no ground and the body\'s centre outside '
                                    'the feet that stay down while the next group swings, the body is first moved '
                                    'this far inside them [m]; 0 = off (the paper: the body tips onto the hanging '
                                    'leg)', min=0.0)
    obstacle_tick: float = param(25.0, 'a swinging leg has met an obstacle when its femur or tibia read is this '
                                 'many ticks from its motion in the air (free swings: within 11)',
                                 min=0.0, min_exclusive=True)

    def __post_init__(self):
        try:
            validate(self)
        except ParameterError as exc:
            raise LocomotionError(f'locomotion {exc}') from None

    def stride_m(self, gait: Gait) -> float:
        """Longest foothold displacement per cycle for ``gait``: max_stride_m if set, else the gait's own."""
        return self.max_stride_m if self.max_stride_m > 0 else gait.max_stride_m

    def turn_rad(self, gait: Gait) -> float:     # largest yaw per cycle: max_turn_rad if set, else the gait's
        return self.max_turn_rad if self.max_turn_rad > 0 else gait.max_turn_rad

    def transfer_s(self) -> float:
        """Duration of one phase outside the settle and the swing-down: leveling plus the next swing-up and
        swing-forward, in sequence or overlapped (``overlap_transfer``)."""
        swing = self.t_swing_up_s + self.t_swing_forward_s
        return max(self.t_level_s, swing) if self.overlap_transfer else swing + self.t_level_s

    def swing_down_s(self) -> float:
        """Expected swing-down duration on flat ground: Eq. 15 moves the goal from lift_m above the
        ground to ground_depth_m below it in t_des_s, and the leg stops at the ground."""
        return self.t_des_s * self.lift_m / (self.lift_m + self.ground_depth_m) if self.lift_m > 0 else self.t_des_s

    def cycle_s(self, gait: Gait) -> float:
        """Expected duration of one gait cycle (every group swings once) on flat ground: the velocity
        command becomes a displacement per cycle with it, so the robot walks at the commanded speed."""
        return gait.n_phases * (self.transfer_s() + self.t_settle_s + self.swing_down_s())

    def saturating_velocity(self, gait: Gait) -> tuple[float, float]:
        """(|v| [m/s], |wz| [rad/s]) beyond which step_phase clamps the stride / turn per cycle."""
        c = self.cycle_s(gait)
        return self.stride_m(gait) / c, self.turn_rad(gait) / c


@dataclass(frozen=True)
class VelocityCommand:
    """Desired body velocity (as geometry_msgs/Twist): vx, vy [m/s], wz [rad/s]."""

    vx: float = 0.05
    vy: float = 0.0
    wz: float = 0.0

    def __post_init__(self):
        for name in ('vx', 'vy', 'wz'):
            if not math.isfinite(getattr(self, name)):
                raise LocomotionError(f'velocity command {name} is not finite: {getattr(self, name)!r}')
