"""A kinematic stand-in for the servo bus, for testing controller logic without physics.

Servos reach their goals instantly, except that a femur cannot push its foot below a flat virtual
ground at ``ground_z_m`` (body frame): it then reads the angle at which the foot touches the ground.
Reads cost t_com of bus time and sample at their start, like the real bus.
"""
import math

from scipy.optimize import brentq

from hexapod_model.description import JOINT_ROLES, parse_joint_name
from hexapod_model.kinematics import forward
from hexapod_model.servo import quantize_tick, theta_to_tick, tick_to_theta


class KinematicGroundBus:
    def __init__(self, robot, ground_z_m=None, t_com_s=0.001):
        self.robot = robot
        self.t_com_s = t_com_s
        self.t = 0.0
        self.goals = {}
        self.ground_z_m = ground_z_m
        self.writes = []
        self.reads = []

    def now(self):
        return self.t

    def sync_write(self, goals_rad):
        for j, v in goals_rad.items():
            assert math.isfinite(v), j
        self.goals.update(goals_rad)
        self.writes.append((self.t, dict(goals_rad)))
        return self.t

    def _femur_actual(self, leg):
        g = [self.goals.get(f'leg{leg}_{r}', 0.0) for r in JOINT_ROLES]
        # one ground height for every leg, or leg -> height (None: no ground under that leg)
        ground = self.ground_z_m.get(leg) if isinstance(self.ground_z_m, dict) else self.ground_z_m
        if ground is None or forward(self.robot, leg, g)[2] >= ground:
            return g[1]
        def height_above_ground(th2):
            return forward(self.robot, leg, [g[0], th2, g[2]])[2] - ground
        return brentq(height_above_ground, g[1], g[1] + 1.5)

    def read_position(self, joint):
        leg, role = parse_joint_name(joint)
        stamp = self.t
        th = self._femur_actual(leg) if role == 'femur' else self.goals.get(joint, 0.0)
        tick = quantize_tick(theta_to_tick(th, self.robot.servo), self.robot.servo)
        self.t += self.t_com_s
        self.reads.append((stamp, joint))
        return float(tick_to_theta(tick, self.robot.servo)), stamp

    def wait_until(self, t):
        self.t = max(self.t, t)
