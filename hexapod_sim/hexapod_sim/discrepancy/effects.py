"""The library of candidate physical effects the discrepancy tool tests.

Each candidate is a one-parameter physical model that the robot description already knows how
to apply (:data:`hexapod_model.description.EFFECT_PARAMS`, ``Robot.joint_effects``): adding an
:class:`~hexapod_model.description.Effect` to the robot changes the swing-down model, the coxa
model and the MuJoCo sim alike. This module only adds what the search needs: the parameter's
plausible range for an AX-12A joint (search bounds), a typical magnitude (for screening), the
scopes it may have, and how to say it in plain language.

Ranges (joint side; nominal values from the robot description in brackets): Coulomb friction
0.005-0.4 N m [0.060], break-away torque 0.07-0.9 N m, viscous damping 0.01-1.5 N m s/rad
[0.20], backlash 0.1-6 deg, torque limit 0.1-1.45 N m [stall 1.5], compliance margin 0.3-10
ticks [0], readout delay 0.3-40 ms, tibia-tip payload 5-400 g.

The servo law (the firmware every servo runs) has candidates of its own, fitted on the whole robot
only, so a difference in it is named as what it is and not spread over joints as joint effects:
extra punch 0.005-0.6 N m [0.047, register 48 = 32], motor damping 0.5-2.5 times the model's
[0.20 N m s/rad: back-EMF and rotor friction], goal latency 0.2-40 ms [goals act at the first
firmware tick at or after their write]. On every analysed joint, viscous damping is the motor
damping and a readout delay is the goal latency (a free leg's replay cannot tell a later goal from
an older read): those joint candidates keep their joint and leg scopes.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from hexapod_model.description import EFFECT_PARAMS, SERVO_LAW_EFFECTS, Effect, Robot


@dataclass(frozen=True)
class Candidate:
    """One candidate effect: name and parameter key as in the description, search range, wording."""

    effect: str
    key: str
    lo: float
    hi: float
    typical: float
    leg_only: bool       # mass_error: a payload belongs to a leg, never to a single joint
    phrase: str          # "the simulation left out <phrase> of about <value>"
    unit: str
    scale: float         # display value = scale * parameter
    digits: int
    two_sided: bool = False   # the parameter's nominal value lies inside its range (a ratio): probed both ways

    @property
    def servo_law(self) -> bool:
        """A term of the servo law: the same firmware on every servo, so fitted on the whole robot only."""
        return self.effect in SERVO_LAW_EFFECTS

    def describe(self, value: float) -> str:
        v = self.scale * value
        return f'{self.phrase} of about {v:.{self.digits}f} {self.unit}'.rstrip()

    def make(self, joints, value: float) -> Effect:
        return Effect(self.effect, tuple(joints), {self.key: float(value)})


CANDIDATES: tuple[Candidate, ...] = (
    Candidate('coulomb_friction', 'tau_c_nm', 0.005, 0.4, 0.05, False, 'extra Coulomb friction', 'N m', 1.0, 3),
    Candidate('static_friction', 'tau_s_nm', 0.07, 0.9, 0.2, False, 'static (break-away) friction', 'N m', 1.0, 3),
    Candidate('viscous_damping', 'b_nms_per_rad', 0.01, 1.5, 0.15, False, 'extra viscous damping', 'N m s/rad',
              1.0, 3),
    Candidate('backlash', 'width_rad', math.radians(0.1), math.radians(6.0), math.radians(1.2), False,
              'gear backlash', 'degrees', 180.0 / math.pi, 2),
    Candidate('torque_saturation', 'tau_max_nm', 0.1, 1.45, 0.6, False, 'a torque limit (weak servo or supply sag)',
              'N m', 1.0, 2),
    Candidate('compliance_deadband', 'margin_ticks', 0.3, 10.0, 2.0, False, 'a compliance dead-band', 'ticks', 1.0, 1),
    Candidate('readout_delay', 'delay_s', 0.0003, 0.04, 0.005, False, 'a position readout delay', 'ms', 1000.0, 1),
    Candidate('mass_error', 'payload_kg', 0.005, 0.4, 0.05, True, 'an extra mass at the foot', 'g', 1000.0, 0),
    Candidate('punch', 'extra_punch_nm', 0.005, 0.6, 0.05, False,
              'extra servo punch (least drive outside the compliance margin)', 'N m',
              1.0, 3),
    Candidate('motor_damping', 'ratio', 0.5, 2.5, 1.15, False, 'a motor damping (back-EMF and rotor friction)',
              'times the model\'s', 1.0, 2, two_sided=True),
    Candidate('goal_latency', 'delay_s', 0.0002, 0.04, 0.002, False,
              'a goal latency (every goal acts later than the model assumes; reads older than their stamps on '
              'every joint look the same)', 'ms', 1000.0, 2),
)

BY_NAME = {c.effect: c for c in CANDIDATES}
assert set(BY_NAME) == set(EFFECT_PARAMS) and all(EFFECT_PARAMS[c.effect] == (c.key,) for c in CANDIDATES)


def scope_name(joints, analysed) -> str:
    """Plain-language scope: 'leg 3 tibia', 'leg 3', 'the whole robot' or a list."""
    joints = tuple(joints)
    analysed = tuple(analysed)
    if len(joints) > 1 and set(joints) >= set(analysed):
        return 'the whole robot'
    legs = sorted({j.leg for j in joints})
    if len(joints) == 1:
        return f'leg {joints[0].leg} {joints[0].role}'
    if len(legs) == 1 and set(joints) >= {j for j in analysed if j.leg == legs[0]}:
        return f'leg {legs[0]}'
    return ', '.join(f'leg {j.leg} {j.role}' for j in joints)


def apply(robot: Robot, effects) -> Robot:
    """The robot with ``effects`` added (the one path the model and the sim share)."""
    return robot.with_effects(tuple(effects))
