"""model_node: serves swing-down predictions (paper CalcModel, Eq. 11-17) on a ROS service.

Service ``/predict_swing_down`` (hexapod_msgs/srv/PredictSwingDown): for L legs swinging down
together, read sequentially in the given order, returns per control step and leg the read instant,
the femur goal, the predicted femur position, the predicted error and the Eq. 17 threshold.
The node keeps one compiled :class:`LegModel` per leg, so a request costs about a millisecond.
"""
from __future__ import annotations

from rclpy.node import Node

from hexapod_model.contract import PREDICT_SWING_DOWN
from hexapod_model.description import LEGS, DescriptionError
from hexapod_model.node_params import NodeParams, node_help, run_node
from hexapod_model.param_schema import MODEL_NODE, RobotSource
from hexapod_model.swing_model import LegModel, SwingDownError, predict_swing_down


class ModelNode(Node):
    def __init__(self, **node_kwargs):
        super().__init__('model_node', **node_kwargs)
        self.robot = NodeParams(self).declare(RobotSource).load()
        self.models = {leg: LegModel(self.robot, leg) for leg in LEGS}
        from hexapod_msgs.srv import PredictSwingDown
        self.srv = self.create_service(PredictSwingDown, PREDICT_SWING_DOWN, self.on_request)
        self.get_logger().info(f'serving {self.resolve_service_name(PREDICT_SWING_DOWN)} for robot {self.robot.name!r}')

    def on_request(self, req, resp):
        legs = list(req.legs)
        n = len(legs)
        arrays = [req.femur_init_rad, req.tibia_init_rad, req.femur_fin_rad, req.tibia_fin_rad]
        speeds = [req.femur_init_rad_s, req.tibia_init_rad_s]
        moving = bool(len(speeds[0]) or len(speeds[1]))     # empty: every leg starts at rest
        if moving:
            arrays += speeds
        if n == 0 or any(len(a) != n for a in arrays) or any(not 1 <= leg <= 6 for leg in legs):
            resp.success = False
            resp.message = (f'legs must be 1..6 and every angle array must have one entry per leg '
                            f'(legs={legs}, lengths={[len(a) for a in arrays]})')
            return resp
        try:
            pred = predict_swing_down(
                self.robot, legs, list(zip(req.femur_init_rad, req.tibia_init_rad)),
                list(zip(req.femur_fin_rad, req.tibia_fin_rad)), req.t_des_s, req.t_com_s,
                epsilon_tick=req.epsilon_tick, n_steps=req.max_steps or None, models=self.models,
                qd0_rad_s=list(zip(*speeds)) if moving else None)
        except SwingDownError as exc:
            resp.success, resp.message = False, str(exc)
            return resp
        resp.success = True
        resp.message = f'{pred.t_read_s.shape[0]} steps x {n} legs, t_con = {pred.t_con_s * 1e3:.1f} ms'
        resp.t_read_s = pred.t_read_s.ravel().tolist()
        resp.theta_des_tick = pred.theta_des_tick.ravel().astype(float).tolist()
        resp.theta_est_tick = pred.theta_est_tick.ravel().tolist()
        resp.err_est_tick = pred.err_est_tick.ravel().tolist()
        resp.threshold_tick = pred.threshold_tick.ravel().tolist()
        return resp


def main(args=None):
    run_node('model_node', ModelNode, node_help('model_node', __doc__, MODEL_NODE.schemas), args,
             errors=(DescriptionError,), spec=MODEL_NODE)


if __name__ == '__main__':
    main()
