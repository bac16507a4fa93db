"""The robot description: paper values, validation with named errors, overlays."""
import math
from pathlib import Path

import pytest
import yaml

from hexapod_model.description import (
    ALL_JOINTS,
    LEGS,
    DescriptionError,
    Effect,
    default_description_path,
    effects_to_overlay,
    load_robot,
    parse_joint_name,
    robot_from_dict,
)


@pytest.fixture(scope='module')
def robot():
    return load_robot()


def test_paper_tables(robot):
    assert robot.dh['coxa'].a_m == 0.052 and robot.dh['femur'].a_m == 0.066 and robot.dh['tibia'].a_m == 0.138
    assert robot.dh['coxa'].alpha_rad == pytest.approx(math.pi / 2)
    assert robot.dh['femur'].theta_off_rad == -0.22 and robot.dh['tibia'].theta_off_rad == -0.81
    betas = [robot.leg(i).beta_rad for i in LEGS]
    assert betas == pytest.approx([math.pi / 4, 7 * math.pi / 4, 3 * math.pi / 4, 5 * math.pi / 4,
                                   math.pi / 2, 3 * math.pi / 2])
    assert robot.leg(5).py_m == 0.1005 and robot.leg(6).py_m == -0.1005   # the paper's typo fixed
    s = robot.servo
    assert (s.rotor_inertia_kgm2, s.rotor_damping_nms, s.gear_ratio) == (1.03e-7, 3.12e-6, 254.0)
    assert s.reflected_inertia_kgm2 == pytest.approx(1.03e-7 * 254 ** 2)
    assert s.reflected_coulomb_nm == pytest.approx(2.37e-4 * 254)
    assert s.gain_nm_per_tick == pytest.approx(1.5 / 32)
    assert s.rad_per_tick == pytest.approx(math.radians(300) / 1024)
    assert robot.total_mass_kg == 2.3
    assert robot.body_mass_kg == pytest.approx(2.3 - 6 * 0.21)


def test_joint_names_and_bus_ids(robot):
    assert len(ALL_JOINTS) == 18 and ALL_JOINTS[4] == 'leg2_femur'
    assert [j.servo_id for j in robot.bus.joints] == list(range(1, 19))
    assert parse_joint_name('leg6_tibia') == (6, 'tibia')
    for bad in ('leg7_femur', 'leg1_knee', 'femur', 'legX_coxa'):
        with pytest.raises(DescriptionError, match='leg<1..6>'):
            parse_joint_name(bad)


def _write(tmp_path, data):
    p = tmp_path / 'robot.yaml'
    p.write_text(yaml.safe_dump(data))
    return p


def _base():
    return yaml.safe_load(default_description_path().read_text())


@pytest.mark.parametrize('mutate, message', [
    (lambda d: d['servo'].pop('gear_ratio'), "missing key 'gear_ratio'"),
    (lambda d: d['dh']['femur'].update(a_m=float('nan')), 'dh.femur.a_m: must be finite'),
    (lambda d: d['links']['tibia'].update(mass_kg=-1), 'links.tibia.mass_kg: must be > 0'),
    (lambda d: d['servo'].update(stall_torque_nm='strong'), 'servo.stall_torque_nm: expected a number'),
    (lambda d: d['legs'].pop(), 'exactly one entry for each leg'),
    (lambda d: d['legs'][1].update(leg=None), r'exactly one entry for each leg 1..6 \(leg: \[1, None, 3'),
    (lambda d: d['legs'][1].update(leg=[1, 2]), 'exactly one entry for each leg'),
    (lambda d: d['legs'][1].update(leg='2'), 'exactly one entry for each leg'),
    (lambda d: d['legs'][1].update(leg=2.0), 'exactly one entry for each leg'),
    (lambda d: d['bus'].update(joints={'leg1_coxa': {'servo_id': 2}}), 'servo IDs must be unique'),
    (lambda d: d['bus'].update(joints={'leg1_coxa': {'direction': 0}}), r'direction: must be \+1 or -1'),
    (lambda d: d['joint_limits_rad'].update(femur=[1, -1]), 'must be below high'),
    (lambda d: d.update(total_mass_kg=1.0), 'not more than six legs'),
    (lambda d: d.update(effects=[{'effect': 'warp_drive', 'joints': ['leg1_femur'], 'params': {}}]),
     "unknown effect 'warp_drive'"),
    (lambda d: d.update(effects=[{'effect': 'backlash', 'joints': ['leg1_femur'], 'params': {'w': 1}}]),
     "takes exactly \\['width_rad'\\]"),
    (lambda d: d['servo'].update(typo_key=1), "servo: unknown key 'typo_key'"),
    (lambda d: d['servo'].update(punch=0), r'servo.punch: the AX-12A takes 32..1023'),
    (lambda d: d['servo'].update(moving_speed=200), 'servo.moving_speed: the servo model has no speed control'),
])
def test_bad_description_is_named(tmp_path, mutate, message):
    d = _base()
    mutate(d)
    with pytest.raises(DescriptionError, match=message):
        load_robot(_write(tmp_path, d))


def test_unreadable_and_non_yaml(tmp_path):
    with pytest.raises(DescriptionError, match='missing.yaml: no such file$') as info:
        load_robot(tmp_path / 'missing.yaml')
    assert str(info.value).count('missing.yaml') == 1          # the path once, not two or three times
    p = tmp_path / 'bad.yaml'
    p.write_text('servo: [unclosed')
    with pytest.raises(DescriptionError, match=f'^{p}: not valid YAML: line 1, column 17: ') as info:
        load_robot(p)
    assert '\n' not in str(info.value) and 'unicode string' not in str(info.value)   # one line, the file once
    assert str(info.value).count('bad.yaml') == 1


def test_overlay_merges_and_resolves_effects(tmp_path, robot):
    eff = [Effect('static_friction', ('leg3_tibia',), {'tau_s_nm': 0.12}),
           Effect('mass_error', ('leg2_femur', 'leg2_tibia'), {'payload_kg': 0.05}),
           Effect('torque_saturation', tuple(ALL_JOINTS), {'tau_max_nm': 1.1})]
    ov = tmp_path / 'overlay.yaml'
    data = effects_to_overlay(eff)
    data['servo'] = {'stall_torque_nm': 1.4}
    ov.write_text(yaml.safe_dump(data))
    r2 = load_robot(overlays=[ov])
    assert r2.servo.stall_torque_nm == 1.4 and r2.servo.gear_ratio == robot.servo.gear_ratio
    assert r2.joint_effects('leg3_tibia').static_friction_nm == 0.12
    assert r2.joint_effects('leg3_femur').static_friction_nm == 0.0
    assert r2.joint_effects('leg5_coxa').torque_max_nm == 1.1
    assert r2.leg_payload_kg(2) == pytest.approx(0.05) and r2.leg_payload_kg(1) == 0.0
    assert robot.effects == ()


# A misspelt key at ANY level of a description or an overlay is refused, named
# (dotted path), and the message names the overlay file the user edits, once.
@pytest.mark.parametrize('overlay, key', [
    ({'efects': []}, "unknown key 'efects' (did you mean 'effects'?)"),
    ({'total_mas_kg': 2.5}, "unknown key 'total_mas_kg' (did you mean 'total_mass_kg'?)"),
    ({'bus': {'baudrate': 57600}}, "bus: unknown key 'baudrate'"),
    ({'bus': {'joints': {'leg1_coxa': {'servoid': 3}}}}, "bus.joints.leg1_coxa: unknown key 'servoid'"),
    ({'bus': {'joints': {'leg7_coxa': {'servo_id': 3}}}}, "bus.joints: unknown key 'leg7_coxa'"),
    ({'dh': {'femr': {'a_m': 0.07}}}, "dh: unknown key 'femr'"),
    ({'dh': {'femur': {'am': 0.07}}}, "dh.femur: unknown key 'am'"),
    ({'links': {'tibia': {'mas_kg': 0.1}}}, "links.tibia: unknown key 'mas_kg'"),
    ({'servo': {'gear_ration': 200}}, "servo: unknown key 'gear_ration'"),
    ({'joint_limits_rad': {'tibiaa': [0, 1]}}, "joint_limits_rad: unknown key 'tibiaa'"),
    ({'default_stance': {'femur': 0.4}}, "default_stance: unknown key 'femur'"),
    ({'effects': [{'effect': 'backlash', 'joint': ['leg1_femur'], 'params': {'width_rad': 0.01}}]},
     "effects[0]: unknown key 'joint'"),
])
def test_unknown_key_in_overlay_is_refused_at_every_level(tmp_path, overlay, key):
    ov = tmp_path / 'my_overlay.yaml'
    ov.write_text(yaml.safe_dump(overlay))
    with pytest.raises(DescriptionError) as info:
        load_robot(overlays=[ov])
    msg = str(info.value)
    assert key in msg and msg.startswith(f'{ov}: ')
    assert msg.count(str(ov)) == 1 and 'build/' not in msg and 'install/' not in msg


def test_unknown_top_level_key_in_a_description_dict_is_refused():
    d = _base()
    d['legss'] = d['legs']
    with pytest.raises(DescriptionError, match="unknown key 'legss'"):
        robot_from_dict(d)


def test_error_after_merge_names_the_overlay_and_the_source_description(tmp_path):
    ov = tmp_path / 'heavy.yaml'
    ov.write_text('links:\n  tibia: {mass_kg: -1}\n')
    with pytest.raises(DescriptionError) as info:
        load_robot(overlays=[ov])
    msg = str(info.value)
    assert msg.startswith(f'{ov}: links.tibia.mass_kg: must be > 0')
    # the packaged description is named by its source file, not the copy under build/ or install/
    src = Path(__file__).resolve().parents[1] / 'hexapod_model' / 'data' / 'robot.yaml'
    assert f'merged over {src}' in msg and '/build/' not in msg and '/install/' not in msg
