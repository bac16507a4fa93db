"""The robot description: paper values, validation with named errors, overlays."""
import math

import pytest
import yaml

from hexapod_model.description import (ALL_JOINTS, DescriptionError, Effect, effects_to_overlay,
                                       load_robot, parse_joint_name, default_description_path)


@pytest.fixture(scope='module')
def robot():
    return load_robot()


def test_paper_tables(robot):
    assert robot.dh['coxa'].a_m == 0.052 and robot.dh['femur'].a_m == 0.066 and robot.dh['tibia'].a_m == 0.138
    assert robot.dh['coxa'].alpha_rad == pytest.approx(math.pi / 2)
    assert robot.dh['femur'].theta_off_rad == -0.22 and robot.dh['tibia'].theta_off_rad == -0.81
    betas = [robot.leg(i).beta_rad for i in range(1, 7)]
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
    (lambda d: d['bus'].update(joints={'leg1_coxa': {'servo_id': 2}}), 'servo IDs must be unique'),
    (lambda d: d['bus'].update(joints={'leg1_coxa': {'direction': 0}}), r'direction: must be \+1 or -1'),
    (lambda d: d['joint_limits_rad'].update(femur=[1, -1]), 'must be below high'),
    (lambda d: d.update(total_mass_kg=1.0), 'not more than six legs'),
    (lambda d: d.update(effects=[{'effect': 'warp_drive', 'joints': ['leg1_femur'], 'params': {}}]),
     "unknown effect 'warp_drive'"),
    (lambda d: d.update(effects=[{'effect': 'backlash', 'joints': ['leg1_femur'], 'params': {'w': 1}}]),
     "takes exactly \\['width_rad'\\]"),
    (lambda d: d['servo'].update(typo_key=1), "unknown key\\(s\\) \\['typo_key'\\]"),
])
def test_bad_description_is_named(tmp_path, mutate, message):
    d = _base()
    mutate(d)
    with pytest.raises(DescriptionError, match=message):
        load_robot(_write(tmp_path, d))


def test_unreadable_and_non_yaml(tmp_path):
    with pytest.raises(DescriptionError, match='cannot read'):
        load_robot(tmp_path / 'missing.yaml')
    p = tmp_path / 'bad.yaml'
    p.write_text('servo: [unclosed')
    with pytest.raises(DescriptionError, match='not valid YAML'):
        load_robot(p)


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
