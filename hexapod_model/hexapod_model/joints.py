"""The robot's joints as one typed value: :class:`Joint` (a leg and a role), named ``leg3_femur``.

The recording contract, the robot description's YAML and the tools' outputs name joints as text;
inside, a joint is a :class:`Joint`: ``joint.leg`` and ``joint.role`` without re-parsing a name.
Joints order leg by leg, coxa, femur, tibia (the contract's order, and that of their names).
No rclpy, no numpy.
"""
from __future__ import annotations

from dataclasses import dataclass

JOINT_ROLES = ('coxa', 'femur', 'tibia')
LEGS = (1, 2, 3, 4, 5, 6)
NAME_FORM = 'leg<1..6>_<coxa|femur|tibia>'


class JointNameError(ValueError):
    """A joint name or a (leg, role) pair that names no joint of the robot."""


@dataclass(frozen=True, order=True, slots=True)
class Joint:
    """One joint: ``leg`` 1..6 and ``role`` 'coxa', 'femur' or 'tibia'; ``str()`` is its name."""

    leg: int
    role: str

    def __post_init__(self):
        if self.leg not in LEGS or self.role not in JOINT_ROLES or isinstance(self.leg, bool):
            raise JointNameError(f'no joint for leg={self.leg!r} role={self.role!r}')

    def __str__(self) -> str:
        return f'leg{self.leg}_{self.role}'

    def __format__(self, spec: str) -> str:
        return format(str(self), spec)          # f'{joint:11s}' pads the name

    @classmethod
    def parse(cls, name: str) -> Joint:
        """The joint named ``name`` (``leg3_femur``); :class:`JointNameError` on any other text."""
        joint = _BY_NAME.get(name) if isinstance(name, str) else None
        if joint is None:
            raise JointNameError(f'joint name {name!r} is not of the form {NAME_FORM}')
        return joint

    @classmethod
    def of(cls, joint: Joint | str) -> Joint:
        """``joint`` itself, or the joint a name names (where text comes in: a file, a command line)."""
        return joint if isinstance(joint, cls) else cls.parse(joint)


def joint_names(joints) -> list[str]:
    """The names of ``joints``, in their order (where joints leave as text: JSON, a message)."""
    return [str(j) for j in joints]


JOINTS = tuple(Joint(leg, role) for leg in LEGS for role in JOINT_ROLES)   # the contract's order
LEG_JOINTS = {leg: JOINTS[3 * k:3 * k + 3] for k, leg in enumerate(LEGS)}  # leg -> its joints, coxa to tibia
ALL_JOINTS = tuple(str(j) for j in JOINTS)                                  # their names, in that order
_BY_NAME = dict(zip(ALL_JOINTS, JOINTS))
