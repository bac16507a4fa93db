"""OdometryTap on a fake bus whose joint angles put the feet on fixed world footholds under a body that
moves along x: the odometry follows the body through a change of stance group (the hand-over)."""
import numpy as np
import pytest

from hexapod_locomotion.core.odometry import LegOdometry
from hexapod_locomotion.core.odometry_tap import OdometryTap
from hexapod_model.description import ALL_JOINTS, JOINT_ROLES, LEGS, joint_name, load_robot
from hexapod_model.kinematics import inverse, stance_feet

ROBOT = load_robot()


class WorldBus:
    """Reads give the angles that put each foot on its world foothold (or in the air above it)."""

    t_com_s = 0.001

    def __init__(self):
        self.t, self.body_x = 0.0, 0.0
        self.footholds = stance_feet(ROBOT)            # world frame = body frame at the start
        self.lift = np.zeros(6)
        self.writes = []

    def angles(self, leg):
        foot = self.footholds[leg - 1] - [self.body_x, 0, 0] + [0, 0, self.lift[leg - 1]]
        return inverse(ROBOT, leg, foot)

    def now(self):
        return self.t

    def read_position(self, joint):
        leg = int(joint[3])
        theta = self.angles(leg)[JOINT_ROLES.index(joint.split('_')[1])]
        self.t += self.t_com_s
        return float(theta), self.t

    def sync_write(self, goals):
        self.writes.append(dict(goals))
        return self.t

    def wait_until(self, t):
        self.t = max(self.t, t)


def _sweep(tap, bus, joints=ALL_JOINTS):
    """Read ``joints`` in turn, then update: the fake body jumps between sweeps, so an update only sees
    one body position once every joint has been read (a real body moves little between reads)."""
    for j in joints:
        tap.read_position(j)
    tap.update(bus.now())


def test_odometry_follows_the_body_through_a_stance_change():
    bus = WorldBus()
    swinging = set()
    # no periodic update (period 1e9 s): only at a change of the feet on the ground and after each sweep
    tap = OdometryTap(bus, ROBOT, lambda: np.array([leg not in swinging for leg in LEGS]), [(LegOdometry(), False)],
                      period_s=1e9)
    _sweep(tap, bus)
    for _ in range(10):                    # all six feet down, the body moves 2 cm
        bus.body_x += 0.002
        _sweep(tap, bus)
    swinging.update((1, 3, 5))             # tripod 1-3-5 lifts; the body moves on 2 cm on 2-4-6
    bus.lift[[0, 2, 4]] = 0.03
    for _ in range(10):
        bus.body_x += 0.002
        _sweep(tap, bus)
    bus.footholds[[0, 2, 4], 0] += 0.05    # they land 5 cm further on
    bus.lift[:] = 0.0
    _sweep(tap, bus, [joint_name(leg, 'femur') for leg in (1, 3, 5)])   # the swing-down reads femurs only
    swinging.clear()
    tap.phase_done()                       # landed: coxa and tibia not yet read since
    swinging.update((2, 4, 6))             # the other tripod lifts at once
    bus.lift[[1, 3, 5]] = 0.03
    for _ in range(10):
        bus.body_x += 0.002
        _sweep(tap, bus)
    # within 10 um: the lifted feet that stand in during the hand-over tilt the feet's plane a little;
    # a lost hand-over would lose a sweep's 2 mm
    assert tap.estimate.position[0] == pytest.approx(bus.body_x, abs=1e-5)
    assert tap.estimate.position[1] == pytest.approx(0.0, abs=1e-5)
    assert tap.estimate.rpy[2] == pytest.approx(0.0, abs=1e-4)


def test_the_tap_passes_every_call_through_unchanged():
    bus = WorldBus()
    tap = OdometryTap(bus, ROBOT, lambda: np.ones(6, bool), [(LegOdometry(), False)])
    assert tap.read_position('leg2_tibia') == (pytest.approx(float(bus.angles(2)[2])), pytest.approx(0.001))
    tap.sync_write({'leg1_coxa': 0.1})
    assert bus.writes == [{'leg1_coxa': 0.1}]
    tap.wait_until(0.5)
    assert tap.now() == 0.5 and tap.t_com_s == bus.t_com_s
