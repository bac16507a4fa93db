"""The one robot description: YAML -> validated, frozen dataclasses.

Every component (swing-down model, MuJoCo MJCF, driver, controller) obtains the robot through
:func:`load_robot`. Units are part of every field name. Angles are the DH joint variable
``theta`` of the paper (``psi = theta + theta_off``), in radians, unless a name says ``tick``.

An *overlay* YAML (for example the output of the discrepancy tool) is merged over the base
description: mappings merge key by key, lists and scalars replace, and ``effects`` lists are
appended.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, fields, replace
from importlib import resources
from pathlib import Path
from typing import Any, Iterable, Mapping

import yaml

from hexapod_model.dictionary import TERM_PARAMS, check_params
from hexapod_model.joints import ALL_JOINTS, JOINT_ROLES, LEGS, Joint, JointNameError, joint_names
from hexapod_model.yaml_files import source_path, yaml_problem


class DescriptionError(ValueError):
    """The robot description (or an overlay) is malformed; the message names the offending key."""


def joint_name(leg: int, role: str) -> str:
    """Joint name of the recording contract, e.g. ``leg3_femur`` (the name of a :class:`Joint`)."""
    try:
        return str(Joint(leg, role))
    except JointNameError as exc:
        raise DescriptionError(str(exc)) from None


def parse_joint_name(name: str) -> tuple[int, str]:
    """Inverse of :func:`joint_name`; raises :class:`DescriptionError` on a foreign name."""
    try:
        j = Joint.parse(name)
    except JointNameError as exc:
        raise DescriptionError(str(exc)) from None
    return j.leg, j.role


# ----------------------------------------------------------------------------- dataclasses
@dataclass(frozen=True)
class DHLink:
    """One row of the paper's Table 1."""

    alpha_rad: float
    a_m: float
    d_m: float
    theta_off_rad: float


@dataclass(frozen=True)
class LegMount:
    """One column of the paper's Table 2: where a leg's coxa frame sits in the body frame."""

    leg: int
    beta_rad: float
    px_m: float
    py_m: float


@dataclass(frozen=True)
class LinkInertial:
    """Mass properties of one leg link; the COM lies on the link axis."""

    mass_kg: float
    com_from_joint_m: float
    inertia_about_com_kgm2: float


@dataclass(frozen=True)
class ServoParams:
    """Dynamixel AX-12A actuator (paper Table 3, motor side) and its position controller."""

    rotor_inertia_kgm2: float
    rotor_damping_nms: float
    gear_ratio: float
    torque_constant_nm_per_a: float
    coulomb_friction_nm: float
    stall_torque_nm: float
    compliance_slope_ticks: int
    compliance_margin_ticks: int
    punch: int               # register 48 (0..1023 of the full drive); the driver writes it
    moving_speed: int        # register 32 (0 = full speed, no speed control); the driver writes it
    ticks_per_range: int
    range_deg: float
    center_tick: int
    control_period_s: float
    winding_resistance_ohm: float
    supply_voltage_v: float
    thermal_resistance_k_per_w: float
    thermal_time_constant_s: float
    shutdown_temperature_c: float

    # Values reflected to the joint (output) side, as they act in the swing-down model (Eq. 14).
    @property
    def reflected_inertia_kgm2(self) -> float:
        return self.rotor_inertia_kgm2 * self.gear_ratio ** 2

    @property
    def reflected_damping_nms_per_rad(self) -> float:
        return self.rotor_damping_nms * self.gear_ratio ** 2

    @property
    def reflected_coulomb_nm(self) -> float:
        return self.coulomb_friction_nm * self.gear_ratio

    @property
    def rad_per_tick(self) -> float:
        return math.radians(self.range_deg) / self.ticks_per_range

    @property
    def gain_nm_per_tick(self) -> float:
        """Proportional gain of Eq. 13 in output units: stall torque over the compliance slope."""
        return self.stall_torque_nm / self.compliance_slope_ticks

    @property
    def max_tick(self) -> int:
        return self.ticks_per_range - 1

    @property
    def punch_nm(self) -> float:
        """The punch as joint torque: the register's share of the full drive (1023 = the stall torque)."""
        return self.stall_torque_nm * self.punch / PUNCH_FULL_SCALE


@dataclass(frozen=True)
class BusJoint:
    """How one joint's servo sits on the bus: tick = center + direction * theta / rad_per_tick + offset."""

    joint: str
    servo_id: int
    direction: int
    offset_ticks: int


@dataclass(frozen=True)
class BusConfig:
    baud_rate: int
    t_com_s: float
    joints: tuple[BusJoint, ...]

    def by_joint(self, joint) -> BusJoint:
        """The bus entry of ``joint`` (a :class:`Joint` or its name)."""
        name = str(joint)
        for j in self.joints:
            if j.joint == name:
                return j
        raise DescriptionError(f'no bus entry for joint {name!r}')


PUNCH_FULL_SCALE = 1023    # AX-12A drive registers (torque limit, punch): 1023 = the full drive

EFFECT_PARAMS = {
    'coulomb_friction': ('tau_c_nm',),
    'static_friction': ('tau_s_nm',),
    'viscous_damping': ('b_nms_per_rad',),
    'backlash': ('width_rad',),
    'torque_saturation': ('tau_max_nm',),
    'compliance_deadband': ('margin_ticks',),
    'readout_delay': ('delay_s',),
    'mass_error': ('payload_kg',),
    # the servo law (the firmware, the same on every servo): fitted robot-wide
    'punch': ('extra_punch_nm',),
    'motor_damping': ('ratio',),
    'goal_latency': ('delay_s',),
}
SERVO_LAW_EFFECTS = ('punch', 'motor_damping', 'goal_latency')


@dataclass(frozen=True)
class Effect:
    """A physical effect beyond the nominal model, on some joints (all joint-side units).

    coulomb_friction: extra Coulomb friction torque; static_friction: break-away torque (at rest
    the joint sticks until the drive torque exceeds it; it then slides with Coulomb friction);
    viscous_damping: extra viscous damping; backlash: total play of the gear train;
    torque_saturation: output torque limit below the stall torque; compliance_deadband: the servo
    outputs no torque while |goal - present| <= margin; readout_delay: the reported position is
    older than its stamp; mass_error: point mass at the tibia tip of the joint's leg.
    Servo-law terms (:data:`SERVO_LAW_EFFECTS`): punch: the least drive outside the compliance
    margin is higher than the description's punch by ``extra_punch_nm``; motor_damping: the
    reflected motor damping (back-EMF and rotor friction) is ``ratio`` times the description's;
    goal_latency: a written goal takes effect ``delay_s`` later than the model assumes (the first
    firmware tick at or after its stamp plus the delay). Terms beyond these: :mod:`hexapod_model.dictionary`.
    """

    effect: str
    joints: tuple[Joint, ...]        # given as joints or their names
    params: Mapping[str, float]

    def __post_init__(self):
        object.__setattr__(self, 'joints', tuple(Joint.of(j) for j in self.joints))


@dataclass(frozen=True)
class JointEffects:
    """All effects resolved for one joint (zeros/None = nominal behaviour)."""

    extra_coulomb_nm: float = 0.0
    static_friction_nm: float = 0.0
    extra_damping_nms_per_rad: float = 0.0
    backlash_width_rad: float = 0.0
    torque_max_nm: float | None = None
    deadband_margin_ticks: float = 0.0
    readout_delay_s: float = 0.0
    payload_kg: float = 0.0
    extra_punch_nm: float = 0.0
    damping_ratio: float = 1.0
    goal_latency_s: float = 0.0


@dataclass(frozen=True)
class Robot:
    name: str
    gravity_mps2: float
    total_mass_kg: float
    dh: Mapping[str, DHLink]
    legs: tuple[LegMount, ...]
    links: Mapping[str, LinkInertial]
    servo: ServoParams
    electronics_idle_power_w: float
    joint_limits_rad: Mapping[str, tuple[float, float]]
    default_stance_rad: tuple[float, float, float]
    bus: BusConfig
    effects: tuple[Effect, ...] = field(default=())

    def leg(self, leg: int) -> LegMount:
        for m in self.legs:
            if m.leg == leg:
                return m
        raise DescriptionError(f'no leg {leg!r} (legs are 1..6)')

    @property
    def leg_mass_kg(self) -> float:
        return sum(self.links[r].mass_kg for r in JOINT_ROLES)

    @property
    def body_mass_kg(self) -> float:
        """Trunk mass: the total mass minus six legs."""
        return self.total_mass_kg - 6 * self.leg_mass_kg

    def joint_limits(self, name: str) -> tuple[float, float]:
        return self.joint_limits_rad[parse_joint_name(name)[1]]

    def joint_effects(self, joint: Joint | str) -> JointEffects:
        """Resolve every effect listed for ``joint`` (or the joint of that name) into one :class:`JointEffects`."""
        joint = Joint.of(joint)
        kw: dict[str, Any] = {}
        for eff in self.effects:
            if joint not in eff.joints:
                continue
            p = eff.params
            if eff.effect == 'coulomb_friction':
                kw['extra_coulomb_nm'] = kw.get('extra_coulomb_nm', 0.0) + p['tau_c_nm']
            elif eff.effect == 'static_friction':
                kw['static_friction_nm'] = max(kw.get('static_friction_nm', 0.0), p['tau_s_nm'])
            elif eff.effect == 'viscous_damping':
                kw['extra_damping_nms_per_rad'] = kw.get('extra_damping_nms_per_rad', 0.0) + p['b_nms_per_rad']
            elif eff.effect == 'backlash':
                kw['backlash_width_rad'] = kw.get('backlash_width_rad', 0.0) + p['width_rad']
            elif eff.effect == 'torque_saturation':
                prev = kw.get('torque_max_nm')
                kw['torque_max_nm'] = p['tau_max_nm'] if prev is None else min(prev, p['tau_max_nm'])
            elif eff.effect == 'compliance_deadband':
                kw['deadband_margin_ticks'] = max(kw.get('deadband_margin_ticks', 0.0), p['margin_ticks'])
            elif eff.effect == 'readout_delay':
                kw['readout_delay_s'] = kw.get('readout_delay_s', 0.0) + p['delay_s']
            elif eff.effect == 'mass_error':
                kw['payload_kg'] = kw.get('payload_kg', 0.0) + p['payload_kg']
            elif eff.effect == 'punch':
                kw['extra_punch_nm'] = kw.get('extra_punch_nm', 0.0) + p['extra_punch_nm']
            elif eff.effect == 'motor_damping':
                kw['damping_ratio'] = kw.get('damping_ratio', 1.0) * p['ratio']
            elif eff.effect == 'goal_latency':
                kw['goal_latency_s'] = kw.get('goal_latency_s', 0.0) + p['delay_s']
        return JointEffects(**kw)

    def leg_payload_kg(self, leg: int) -> float:
        """Extra point mass at the tibia tip of ``leg`` (mass_error effects on any of its joints)."""
        total = 0.0
        for eff in self.effects:
            if eff.effect == 'mass_error' and any(j.leg == leg for j in eff.joints):
                total += eff.params['payload_kg']
        return total

    def with_effects(self, effects: Iterable[Effect]) -> 'Robot':
        """A copy of this robot with ``effects`` appended."""
        return replace(self, effects=self.effects + tuple(effects))


def _require(d: Mapping[str, Any], key: str, where: str) -> Any:
    if not isinstance(d, Mapping):
        raise DescriptionError(f'{where}: expected a mapping, got {type(d).__name__}')
    if key not in d:
        raise DescriptionError(f'{where}: missing key {key!r}')
    return d[key]


def _number(value: Any, where: str, *, positive: bool = False, nonneg: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise DescriptionError(f'{where}: expected a number, got {value!r}')
    v = float(value)
    if not math.isfinite(v):
        raise DescriptionError(f'{where}: must be finite, got {value!r}')
    if positive and v <= 0:
        raise DescriptionError(f'{where}: must be > 0, got {value!r}')
    if nonneg and v < 0:
        raise DescriptionError(f'{where}: must be >= 0, got {value!r}')
    return v


def _build(cls, d: Mapping[str, Any], where: str, positive: Iterable[str] = (), nonneg: Iterable[str] = ()):
    if not isinstance(d, Mapping):
        raise DescriptionError(f'{where}: expected a mapping, got {d!r}')
    names = {f.name for f in fields(cls)}
    unknown = set(d) - names
    if unknown:
        raise DescriptionError(f'{where}: unknown key(s) {sorted(unknown)}; expected {sorted(names)}')
    kw = {}
    for f in fields(cls):
        v = _require(d, f.name, where)
        if f.type in ('int',):
            if isinstance(v, bool) or not isinstance(v, int):
                raise DescriptionError(f'{where}.{f.name}: expected an integer, got {v!r}')
            kw[f.name] = v
        else:
            kw[f.name] = _number(v, f'{where}.{f.name}', positive=f.name in positive, nonneg=f.name in nonneg)
    return cls(**kw)


def _parse_effects(raw: Any, where: str = 'effects') -> tuple[Effect, ...]:
    if raw is None:
        return ()
    if not isinstance(raw, list):
        raise DescriptionError(f'{where}: expected a list of effects')
    out = []
    for i, e in enumerate(raw):
        w = f'{where}[{i}]'
        name = _require(e, 'effect', w)
        if name not in EFFECT_PARAMS and name not in TERM_PARAMS:
            raise DescriptionError(f'{w}.effect: unknown effect {name!r}; known: {sorted(EFFECT_PARAMS) + sorted(TERM_PARAMS)}')
        joints = _require(e, 'joints', w)
        if isinstance(joints, str) or not isinstance(joints, list) or not joints:
            raise DescriptionError(f'{w}.joints: expected a non-empty list of joint names')
        for j in joints:
            parse_joint_name(j)
        params = _require(e, 'params', w)
        keys = EFFECT_PARAMS.get(name) or TERM_PARAMS[name]
        if not isinstance(params, Mapping) or set(params) != set(keys):
            raise DescriptionError(f'{w}.params: effect {name!r} takes exactly {list(keys)}, got {params!r}')
        vals = {k: _number(params[k], f'{w}.params.{k}', nonneg=name in EFFECT_PARAMS) for k in keys}
        if name in TERM_PARAMS and check_params(name, vals):   # hexapod_model.dictionary: signs and ranges
            raise DescriptionError(f'{w}.params.{check_params(name, vals)}')
        out.append(Effect(effect=name, joints=tuple(joints), params=vals))
    return tuple(out)


# Keys a description (or an overlay) may hold, at every level: a misspelt key is refused, not
# silently ignored (an overlay's ``efects:`` would otherwise drop the user's effect). Built from
# the dataclasses above, so a new field is allowed here by adding it there.
_ROLE_MAP = 'roles'            # a mapping whose keys are JOINT_ROLES
_JOINT_MAP = 'joints'          # a mapping whose keys are joint names (ALL_JOINTS)
SCHEMA: dict[str, Any] = {
    'name': None, 'gravity_mps2': None, 'total_mass_kg': None, 'electronics_idle_power_w': None,
    'dh': (_ROLE_MAP, {f.name: None for f in fields(DHLink)}),
    'legs': [{f.name: None for f in fields(LegMount)}],
    'links': (_ROLE_MAP, {f.name: None for f in fields(LinkInertial)}),
    'servo': {f.name: None for f in fields(ServoParams)},
    'joint_limits_rad': (_ROLE_MAP, None),
    'default_stance': {f'{r}_rad': None for r in JOINT_ROLES},
    'bus': {'baud_rate': None, 't_com_s': None,
            'joints': (_JOINT_MAP, {f.name: None for f in fields(BusJoint) if f.name != 'joint'})},
    'effects': [{'effect': None, 'joints': None, 'params': None}],   # params: checked per effect
}


def check_keys(data: Any, schema: Any = SCHEMA, where: str = '') -> None:
    """Refuse any key ``data`` holds that :data:`SCHEMA` does not know, naming it (dotted path)."""
    if schema is None or data is None:
        return
    if isinstance(schema, tuple):                      # (roles | joints, value schema)
        kind, sub = schema
        allowed = JOINT_ROLES if kind == _ROLE_MAP else ALL_JOINTS
        schema = {k: sub for k in allowed}
    if isinstance(schema, list):
        if isinstance(data, list):
            for i, item in enumerate(data):
                check_keys(item, schema[0], f'{where}[{i}]')
        return                                         # a wrong type is reported by robot_from_dict
    if not isinstance(data, Mapping):
        return
    unknown = [k for k in data if k not in schema]
    if unknown:
        import difflib
        k = unknown[0]
        hint = difflib.get_close_matches(str(k), [str(x) for x in schema], n=1)
        more = f' (and {len(unknown) - 1} more: {sorted(map(str, unknown[1:]))})' if len(unknown) > 1 else ''
        raise DescriptionError(f'{where + ": " if where else ""}unknown key {k!r}'
                               + (f' (did you mean {hint[0]!r}?)' if hint else f'; expected one of {sorted(map(str, schema))}')
                               + more)
    for k, v in data.items():
        check_keys(v, schema[k], f'{where}.{k}' if where else str(k))


def _legs_from(d: Mapping[str, Any]) -> tuple[LegMount, ...]:
    """The ``legs`` section: one mount per leg 1..6, in leg order."""
    legs_raw = _require(d, 'legs', 'robot')
    ids = [_require(x, 'leg', 'legs[]') for x in legs_raw] if isinstance(legs_raw, list) else None
    if ids is None or not all(type(i) is int for i in ids) or sorted(ids) != list(LEGS):
        raise DescriptionError(f'legs: expected exactly one entry for each leg 1..6 (leg: {ids!r})')
    legs = []
    for x in sorted(legs_raw, key=lambda x: x['leg']):
        w = f'legs[leg={x["leg"]}]'
        extra = set(x) - {'leg', 'beta_rad', 'px_m', 'py_m'}
        if extra:
            raise DescriptionError(f'{w}: unknown key(s) {sorted(extra)}')
        legs.append(LegMount(leg=int(x['leg']), beta_rad=_number(_require(x, 'beta_rad', w), w + '.beta_rad'),
                             px_m=_number(_require(x, 'px_m', w), w + '.px_m'),
                             py_m=_number(_require(x, 'py_m', w), w + '.py_m')))
    return tuple(legs)


def _servo_from(d: Mapping[str, Any]) -> ServoParams:
    """The ``servo`` section, its registers within what the AX-12A takes."""
    servo = _build(ServoParams, _require(d, 'servo', 'robot'), 'servo',
                   positive=('rotor_inertia_kgm2', 'gear_ratio', 'stall_torque_nm', 'range_deg', 'control_period_s',
                             'torque_constant_nm_per_a', 'winding_resistance_ohm', 'supply_voltage_v',
                             'thermal_resistance_k_per_w', 'thermal_time_constant_s'),
                   nonneg=('rotor_damping_nms', 'coulomb_friction_nm'))
    if servo.compliance_slope_ticks <= 0 or servo.ticks_per_range <= 1:
        raise DescriptionError('servo: compliance_slope_ticks and ticks_per_range must be positive')
    if not 32 <= servo.punch <= PUNCH_FULL_SCALE:
        raise DescriptionError(f'servo.punch: the AX-12A takes 32..{PUNCH_FULL_SCALE} (register 48), got {servo.punch}')
    if not 0 <= servo.moving_speed <= PUNCH_FULL_SCALE:
        raise DescriptionError(f'servo.moving_speed: the AX-12A takes 0..{PUNCH_FULL_SCALE} in joint mode '
                               f'(register 32), got {servo.moving_speed}')
    if servo.moving_speed != 0:
        raise DescriptionError('servo.moving_speed: the servo model has no speed control; only 0 (full speed) is '
                               f'modelled, got {servo.moving_speed}')
    if not 0 <= servo.center_tick < servo.ticks_per_range:
        raise DescriptionError('servo.center_tick: must lie within 0..ticks_per_range-1')
    return servo


def _bus_from(d: Mapping[str, Any]) -> BusConfig:
    """The ``bus`` section: every joint's servo (ID, direction, offset; defaults leg by leg), IDs unique."""
    bus_raw = _require(d, 'bus', 'robot')
    overrides = bus_raw.get('joints') or {}
    if not isinstance(overrides, Mapping):
        raise DescriptionError('bus.joints: expected a mapping joint -> {servo_id, direction, offset_ticks}')
    bus_joints = []
    for leg in LEGS:
        for k, r in enumerate(JOINT_ROLES):
            name = joint_name(leg, r)
            o = dict(overrides.get(name) or {})
            unknown = set(o) - {'servo_id', 'direction', 'offset_ticks'}
            if unknown:
                raise DescriptionError(f'bus.joints.{name}: unknown key(s) {sorted(unknown)}')
            bj = BusJoint(joint=name, servo_id=int(o.get('servo_id', 3 * (leg - 1) + k + 1)),
                          direction=int(o.get('direction', 1)), offset_ticks=int(o.get('offset_ticks', 0)))
            if bj.direction not in (-1, 1):
                raise DescriptionError(f'bus.joints.{name}.direction: must be +1 or -1, got {bj.direction}')
            if not 0 <= bj.servo_id <= 253:
                raise DescriptionError(f'bus.joints.{name}.servo_id: must be 0..253, got {bj.servo_id}')
            bus_joints.append(bj)
    for name in overrides:
        parse_joint_name(name)
    ids = [j.servo_id for j in bus_joints]
    if len(set(ids)) != len(ids):
        raise DescriptionError(f'bus.joints: servo IDs must be unique, got {ids}')
    return BusConfig(baud_rate=int(_number(_require(bus_raw, 'baud_rate', 'bus'), 'bus.baud_rate', positive=True)),
                     t_com_s=_number(_require(bus_raw, 't_com_s', 'bus'), 'bus.t_com_s', positive=True),
                     joints=tuple(bus_joints))


def robot_from_dict(d: Mapping[str, Any]) -> Robot:
    """Validate a description mapping and build the frozen :class:`Robot`."""
    check_keys(d)
    dh = {r: _build(DHLink, _require(_require(d, 'dh', 'robot'), r, 'dh'), f'dh.{r}',
                    nonneg=('a_m',)) for r in JOINT_ROLES}
    legs = _legs_from(d)
    links = {r: _build(LinkInertial, _require(_require(d, 'links', 'robot'), r, 'links'), f'links.{r}',
                       positive=('mass_kg', 'inertia_about_com_kgm2'), nonneg=('com_from_joint_m',))
             for r in JOINT_ROLES}
    servo = _servo_from(d)
    lim_raw = _require(d, 'joint_limits_rad', 'robot')
    limits = {}
    for r in JOINT_ROLES:
        lo_hi = _require(lim_raw, r, 'joint_limits_rad')
        if not isinstance(lo_hi, (list, tuple)) or len(lo_hi) != 2:
            raise DescriptionError(f'joint_limits_rad.{r}: expected [low, high]')
        lo, hi = (_number(v, f'joint_limits_rad.{r}') for v in lo_hi)
        if lo >= hi:
            raise DescriptionError(f'joint_limits_rad.{r}: low {lo} must be below high {hi}')
        limits[r] = (lo, hi)
    st = _require(d, 'default_stance', 'robot')
    stance = tuple(_number(_require(st, f'{r}_rad', 'default_stance'), f'default_stance.{r}_rad') for r in JOINT_ROLES)
    for r, v in zip(JOINT_ROLES, stance):
        if not limits[r][0] <= v <= limits[r][1]:
            raise DescriptionError(f'default_stance.{r}_rad={v} is outside joint_limits_rad.{r}={limits[r]}')
    bus = _bus_from(d)
    robot = Robot(
        name=str(_require(d, 'name', 'robot')),
        gravity_mps2=_number(_require(d, 'gravity_mps2', 'robot'), 'gravity_mps2', nonneg=True),
        total_mass_kg=_number(_require(d, 'total_mass_kg', 'robot'), 'total_mass_kg', positive=True),
        dh=dh, legs=legs, links=links, servo=servo,
        electronics_idle_power_w=_number(_require(d, 'electronics_idle_power_w', 'robot'),
                                         'electronics_idle_power_w', nonneg=True),
        joint_limits_rad=limits, default_stance_rad=stance, bus=bus,
        effects=_parse_effects(d.get('effects')),
    )
    if robot.body_mass_kg <= 0:
        raise DescriptionError(f'total_mass_kg={robot.total_mass_kg} is not more than six legs '
                               f'({6 * robot.leg_mass_kg:.3f} kg)')
    return robot


def merge_overlay(base: Mapping[str, Any], overlay: Mapping[str, Any]) -> dict[str, Any]:
    """Deep-merge ``overlay`` onto ``base``: mappings merge, ``effects`` lists append, rest replace."""
    out = dict(base)
    for k, v in overlay.items():
        if k == 'effects':
            out[k] = list(out.get(k) or []) + list(v or [])
        elif isinstance(v, Mapping) and isinstance(out.get(k), Mapping):
            out[k] = merge_overlay(out[k], v)
        else:
            out[k] = v
    return out


def _read_yaml(path: Path) -> dict[str, Any]:
    try:
        text = Path(path).read_text()
    except FileNotFoundError:
        raise DescriptionError(f'{path}: no such file') from None
    except OSError as exc:
        raise DescriptionError(f'{path}: cannot read: {exc.strerror or exc}') from None
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise DescriptionError(f'{path}: not valid YAML: {yaml_problem(exc)}') from None
    if not isinstance(data, Mapping):
        raise DescriptionError(f'{path}: expected a YAML mapping at the top level')
    return dict(data)


def default_description_path() -> Path:
    return Path(str(resources.files('hexapod_model').joinpath('data/robot.yaml')))


def load_robot(path: str | Path | None = None, overlays: Iterable[str | Path] = ()) -> Robot:
    """Load the robot description (default: the packaged ``robot.yaml``) plus overlay files.

    Every file is checked for unknown keys on its own, and an error names the one file that
    causes it (the base description, or the first overlay after whose merge it appears), once.
    """
    base = source_path(path if path else default_description_path())
    data = _read_yaml(base)
    layers = [(base, data)]
    for ov in overlays:
        ov = source_path(ov)
        layers.append((ov, _read_yaml(ov)))
    for src, layer in layers:
        try:
            check_keys(layer)
        except DescriptionError as exc:
            raise DescriptionError(f'{src}: {exc}') from None
    merged = data
    for _src, layer in layers[1:]:
        merged = merge_overlay(merged, layer)
    try:
        return robot_from_dict(merged)
    except DescriptionError as exc:
        error = exc
    # name the file that causes the error: the base, or the first overlay after whose merge it appears
    merged = data
    for src, layer in layers:
        if layer is not data:
            merged = merge_overlay(merged, layer)
        try:
            robot_from_dict(merged)
        except DescriptionError as exc:
            raise DescriptionError(f'{src}: {exc}' + (f' (merged over {base})' if src != base else '')) from None
    raise DescriptionError(f'{" + ".join(str(s) for s, _ in layers)}: {error}') from None


def effects_to_overlay(effects: Iterable[Effect]) -> dict[str, Any]:
    """An overlay mapping (to dump as YAML) that adds ``effects`` to a description."""
    return {'effects': [{'effect': e.effect, 'joints': joint_names(e.joints),
                         'params': {k: float(v) for k, v in e.params.items()}} for e in effects]}
