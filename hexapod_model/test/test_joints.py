"""The joint as one typed value: names in and out, order, keys, and a bad name as one clear error."""
import json

import pytest

from hexapod_model.description import DescriptionError, Effect, joint_name, load_robot, parse_joint_name
from hexapod_model.joints import ALL_JOINTS, JOINTS, LEG_JOINTS, Joint, JointNameError, joint_names


def test_a_joint_is_its_name_and_back():
    j = Joint.parse('leg3_femur')
    assert (j.leg, j.role) == (3, 'femur') and str(j) == 'leg3_femur' and f'{j:>12s}' == '  leg3_femur'
    assert [Joint.parse(n) for n in ALL_JOINTS] == list(JOINTS) and joint_names(JOINTS) == list(ALL_JOINTS)
    assert Joint.of(j) is j and Joint.of('leg3_femur') == j
    assert (joint_name(3, 'femur'), parse_joint_name('leg3_femur')) == ('leg3_femur', (3, 'femur'))


def test_joints_order_and_key_as_their_names_do():
    shuffled = sorted(JOINTS, key=lambda j: (j.role, -j.leg))
    assert [str(j) for j in sorted(shuffled)] == sorted(ALL_JOINTS) == list(ALL_JOINTS)
    table = {Joint(2, 'tibia'): 1}
    assert table[Joint.parse('leg2_tibia')] == 1 and Joint(2, 'tibia') != 'leg2_tibia'
    assert LEG_JOINTS[4] == (Joint(4, 'coxa'), Joint(4, 'femur'), Joint(4, 'tibia'))
    with pytest.raises(TypeError):           # a joint leaves as text only where it is named: JSON never guesses
        json.dumps({'joints': [Joint(1, 'coxa')]})


@pytest.mark.parametrize('name', ['leg7_femur', 'leg0_coxa', 'leg3_knee', 'leg03_femur', 'leg3femur', 'Leg3_femur',
                                  'leg3_femur_x', '', 'coxa'])
def test_a_bad_name_is_one_clear_error(name):
    with pytest.raises(JointNameError, match=r"is not of the form leg<1\.\.6>_<coxa\|femur\|tibia>"):
        Joint.parse(name)
    with pytest.raises(DescriptionError, match='is not of the form'):
        parse_joint_name(name)


def test_a_bad_pair_is_refused():
    for leg, role in ((0, 'coxa'), (7, 'femur'), (3, 'knee'), (True, 'coxa')):
        with pytest.raises(JointNameError, match='no joint for'):
            Joint(leg, role)
    assert issubclass(JointNameError, ValueError)


def test_effects_hold_joints_given_by_name():
    e = Effect('backlash', ('leg5_tibia',), {'width_rad': 0.01})
    assert e.joints == (Joint(5, 'tibia'),) and e == Effect('backlash', (Joint(5, 'tibia'),), {'width_rad': 0.01})
    robot = load_robot().with_effects([e])
    assert robot.joint_effects(Joint(5, 'tibia')).backlash_width_rad == 0.01
    assert robot.joint_effects('leg5_tibia').backlash_width_rad == 0.01
    assert robot.joint_effects(Joint(5, 'femur')).backlash_width_rad == 0.0
    with pytest.raises(JointNameError):
        Effect('backlash', ('leg9_tibia',), {'width_rad': 0.01})
