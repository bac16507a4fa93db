"""A dictionary of physical torque terms beyond the one-parameter effects of the description.

A real robot has physics the one-parameter effects (:data:`hexapod_model.description.EFFECT_PARAMS`)
do not hold. Each term here is an effect kind of the robot description (an overlay lists it under
``effects`` like any other: ``{effect, joints, params}``), applied as physics by the swing-down model
(:mod:`hexapod_model.swing_terms`) and by the MuJoCo sim (``hexapod_sim.physics``); the discrepancy
tool fits them where its named candidates leave a mismatch. All values are joint-side:

- ``cable_spring`` (per joint): a torque ``-k (theta - theta_rest)`` pulling the joint toward a rest
  angle, as a cable or wire loom does. ``stiffness_nm_per_rad`` 0.02-3, ``rest_angle_rad`` -2.6..2.6.
- ``periodic_friction`` (per joint): extra Coulomb friction that varies with the angle, as a gear
  train with an eccentric or damaged wheel has: ``A (1 + cos(2 pi theta / P - phi)) / 2``.
  ``amplitude_nm`` 0.01-0.5, ``period_rad`` 0.05-1.6 (about 3-90 degrees), ``phase_rad`` 0..2 pi.
- ``load_friction`` (per joint): extra Coulomb friction proportional to the torque the gears carry,
  ``mu |tau_servo|`` (mesh friction grows with the tooth load). ``coefficient`` 0.02-1.
- ``supply_sag`` (the whole robot: one supply): the supply's internal resistance ``R`` drops the
  voltage with the total current of all servos, and every servo's drive with it. With ``S`` the sum
  of the servos' stall currents for their firmware torques (``|tau| / (K R)``, the winding current of
  :func:`hexapod_model.servo.winding_current_a` at rest), the drive is ``tau / (1 + R S / V)`` (the
  current that flows is the sagged one). ``resistance_ohm`` 0.05-5.
- ``weak_motor`` (per joint): a weaker or slower motor than its siblings: the whole firmware drive
  (gain, punch and limit) times ``torque_scale``, and the no-load speed times ``speed_scale``: the
  back-EMF damping (stall torque over no-load speed) becomes ``torque_scale / speed_scale`` times the
  description's. ``torque_scale`` 0.2-1.5, ``speed_scale`` 0.2-1.5.

Pure Python; the description imports the parameter table from here (no import the other way).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from hexapod_model.joints import Joint


@dataclass(frozen=True)
class TermParam:
    """One parameter of a term: key (with its unit), plausible range, display unit and scale."""

    key: str
    lo: float
    hi: float
    unit: str
    scale: float = 1.0     # display value = scale * parameter
    digits: int = 3


@dataclass(frozen=True)
class Term:
    """One dictionary term: its name (the description's effect kind), parameters, scope, wording."""

    name: str
    params: tuple[TermParam, ...]
    robot_wide: bool
    phrase: str            # "the simulation left out <phrase> (<values>)"
    start: tuple[float, ...]   # starting values of a fit (a typical robot's)

    @property
    def keys(self) -> tuple[str, ...]:
        return tuple(p.key for p in self.params)

    def describe(self, values) -> str:
        vals = ', '.join(f'{p.key.split("_")[0]} {p.scale * float(values[p.key]):.{p.digits}f} {p.unit}'.rstrip()
                         for p in self.params)
        return f'{self.phrase} ({vals})'


_DEG = 180.0 / math.pi
TERMS: tuple[Term, ...] = (
    Term('cable_spring', (TermParam('stiffness_nm_per_rad', 0.02, 3.0, 'N m/rad'),
                          TermParam('rest_angle_rad', -2.6, 2.6, 'degrees', _DEG, 1)), False,
         'a spring pulling the joint toward a rest angle (a cable or wire loom)', (0.2, 0.0)),
    Term('periodic_friction', (TermParam('amplitude_nm', 0.01, 0.5, 'N m'),
                               TermParam('period_rad', 0.05, 1.6, 'degrees', _DEG, 1),
                               TermParam('phase_rad', 0.0, 2 * math.pi, 'degrees', _DEG, 0)), False,
         'friction that varies with the angle (a gear train: extra friction peaking once per period)',
         (0.1, 0.5, 0.0)),
    Term('load_friction', (TermParam('coefficient', 0.02, 1.0, 'of the servo torque', 1.0, 2),), False,
         'friction proportional to the torque the gears carry (load-dependent mesh friction)', (0.2,)),
    Term('supply_sag', (TermParam('resistance_ohm', 0.05, 5.0, 'ohm', 1.0, 2),), True,
         'a supply that sags with the total current of all servos (internal resistance)', (0.5,)),
    Term('weak_motor', (TermParam('torque_scale', 0.2, 1.5, 'of the stall torque', 1.0, 2),
                        TermParam('speed_scale', 0.2, 1.5, 'of the no-load speed', 1.0, 2)), False,
         'a weaker or slower motor than its siblings', (0.8, 0.8)),
)
BY_TERM = {t.name: t for t in TERMS}
TERM_PARAMS = {t.name: t.keys for t in TERMS}
SIGNED = {'rest_angle_rad'}     # parameters that may be negative


def check_params(name: str, values) -> str | None:
    """What is wrong with a term's parameter values (a message naming the key), or None."""
    for p in BY_TERM[name].params:
        v = values[p.key]
        if p.key not in SIGNED and v < 0:
            return f'{p.key}: must be >= 0, got {v!r}'
        if p.key == 'period_rad' and not v > 0:
            return f'{p.key}: must be > 0, got {v!r}'
        if p.key in ('torque_scale', 'speed_scale') and not v > 0:
            return f'{p.key}: must be > 0, got {v!r}'
    return None


# Per-joint term vector of the swing-down kernel (hexapod_model.swing_terms) and the MuJoCo loop.
(T_K, T_REST, T_PA, T_PP, T_PPH, T_MU, T_TS, T_DS, N_TERMS) = range(9)


def joint_terms(robot, joint) -> np.ndarray:
    """The dictionary terms on ``joint`` (a :class:`~hexapod_model.joints.Joint` or its name; None: on no
    joint) as one vector (indices ``T_*``): spring stiffness and rest angle,
    periodic friction amplitude, period and phase, load-friction coefficient, drive torque scale and
    motor-damping scale (``torque_scale / speed_scale``). Several terms of a kind: springs add (the rest
    angle is their stiffness-weighted mean), load friction adds, scales multiply, the last periodic
    friction counts."""
    joint = None if joint is None else Joint.of(joint)
    v = np.zeros(N_TERMS)
    v[T_PP] = 1.0
    v[T_TS] = v[T_DS] = 1.0
    k_rest = 0.0
    for e in robot.effects:
        if joint not in e.joints or e.effect not in BY_TERM:
            continue
        p = e.params
        if e.effect == 'cable_spring':
            v[T_K] += p['stiffness_nm_per_rad']
            k_rest += p['stiffness_nm_per_rad'] * p['rest_angle_rad']
        elif e.effect == 'periodic_friction':
            v[T_PA], v[T_PP], v[T_PPH] = p['amplitude_nm'], p['period_rad'], p['phase_rad']
        elif e.effect == 'load_friction':
            v[T_MU] += p['coefficient']
        elif e.effect == 'weak_motor':
            v[T_TS] *= p['torque_scale']
            v[T_DS] *= p['torque_scale'] / p['speed_scale']
    if v[T_K] > 0:
        v[T_REST] = k_rest / v[T_K]
    return v


def supply_resistance_ohm(robot) -> float:
    """Internal resistance of the supply from ``supply_sag`` terms (0: an ideal supply)."""
    return sum(e.params['resistance_ohm'] for e in robot.effects if e.effect == 'supply_sag')


def has_terms(robot, joints) -> bool:
    """Whether any dictionary term acts on ``joints`` (a supply sag acts on every joint)."""
    js = {Joint.of(j) for j in joints}
    return any(e.effect in BY_TERM and (e.effect == 'supply_sag' or js & set(e.joints)) for e in robot.effects)


def periodic_friction_nm(v: np.ndarray, theta_rad: float) -> float:
    """Extra Coulomb friction of a periodic-friction term at ``theta`` (the kernels' formula)."""
    return v[T_PA] * 0.5 * (1.0 + math.cos(2.0 * math.pi * theta_rad / v[T_PP] - v[T_PPH]))
