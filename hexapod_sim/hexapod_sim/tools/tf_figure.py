"""``tf_figure OUT.png``: the simulated robot (MuJoCo, offscreen) beside its URDF link frames as a bag
carries them (/tf_static + /tf written by the recorder, read back with ``rosbags``), same pose.

What Foxglove's 3D panel shows from a bag or the live view, drawn here without Foxglove (it cannot
run on a headless machine). Used for docs/img/robot_tf_frames.png:

    ./hexapod run hexapod_sim tf_figure docs/img/robot_tf_frames.png
"""
from __future__ import annotations

import os

os.environ.setdefault('MUJOCO_GL', 'osmesa')
if os.environ['MUJOCO_GL'] == 'osmesa':
    os.environ.setdefault('PYOPENGL_PLATFORM', 'osmesa')

import sys  # noqa: E402
import tempfile  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from hexapod_model.cli_common import make_parser, output_file, positive_float  # noqa: E402
from hexapod_model.description import ALL_JOINTS, LEGS, load_robot  # noqa: E402
from hexapod_model.tf_tree import matrix_of  # noqa: E402


def frames_from_bag(bag: Path) -> dict[str, tuple[str, np.ndarray]]:
    """child -> (parent, 4x4) of the last /tf and the /tf_static in ``bag``, read by rosbags."""
    from rosbags.highlevel import AnyReader
    tree: dict[str, tuple[str, np.ndarray]] = {}
    with AnyReader([bag]) as reader:
        conns = [c for c in reader.connections if c.topic in ('/tf', '/tf_static')]
        for conn, _t, raw in reader.messages(connections=conns):
            for tr in reader.deserialize(raw, conn.msgtype).transforms:
                tree[tr.child_frame_id] = (tr.header.frame_id, matrix_of(tr.transform))
    return tree


def world_poses(tree) -> dict[str, np.ndarray]:
    def pose(frame):
        if frame not in tree:
            return np.eye(4)
        parent, m = tree[frame]
        return pose(parent) @ m
    return {f: pose(f) for f in tree}


def main(argv=None) -> int:
    ap = make_parser('tf_figure', __doc__)
    ap.add_argument('out', metavar='PNG', type=output_file(('.png',)), help='picture to write')
    ap.add_argument('--time', type=positive_float, default=2.0,
                    help='simulated seconds of the scripted tripod gait before the picture (2.0: mid-swing)')
    args = ap.parse_args(argv)
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    from hexapod_sim.bagio.recorder import Recorder
    from hexapod_sim.physics.plant import HexapodSim, run_trajectory
    from hexapod_sim.tools.render import RenderError, _renderer, render_frame, scripted_tripod
    robot = load_robot()
    sim = HexapodSim(robot, terrain='flat')
    run_trajectory(sim, scripted_tripod(robot), args.time, period_s=0.01)   # mid-swing of one tripod
    try:
        renderer = _renderer(sim, 640, 520)
    except RenderError as exc:
        print(f'{ap.prog}: error: {exc}', file=sys.stderr)
        return 2
    image = render_frame(sim, renderer, distance=0.75, azimuth=140.0, elevation=-20.0)
    renderer.close()
    with tempfile.TemporaryDirectory() as tmp:
        with Recorder(Path(tmp) / 'pose', robot=robot) as rec:
            rec.write_tf(sim.now(), ALL_JOINTS, sim.true_joint_angles(), sim.body_pose())
        poses = world_poses(frames_from_bag(Path(tmp) / 'pose'))

    fig = plt.figure(figsize=(11, 4.6), dpi=90)
    ax0 = fig.add_subplot(1, 2, 1)
    ax0.imshow(image)
    ax0.set_axis_off()
    ax0.set_title('MuJoCo (offscreen render)', fontsize=10)
    ax = fig.add_subplot(1, 2, 2, projection='3d')
    for frame, m in poses.items():
        if frame == 'base_link':
            continue
        o = m[:3, 3]
        for k, color in enumerate('rgb'):                  # x y z axes as RViz/Foxglove draw them
            e = o + 0.025 * m[:3, k]
            ax.plot(*zip(o, e), color=color, linewidth=1.2)
    for leg in LEGS:                                       # the chain of each leg
        pts = [poses['trunk'][:3, 3]] + [poses[f'leg{leg}_{r}'][:3, 3] for r in ('coxa', 'femur', 'tibia')] \
            + [poses[f'leg{leg}_foot'][:3, 3]]
        ax.plot(*np.array(pts[1:]).T, color='0.35', linewidth=2.0)
        ax.text(*poses[f'leg{leg}_foot'][:3, 3], f' leg {leg}', fontsize=7)
    ring = [poses[f'leg{leg}_coxa'][:3, 3] for leg in (1, 5, 3, 4, 6, 2, 1)]     # the trunk's outline
    ax.plot(*np.array(ring).T, color='0.1', linewidth=2.5)
    c = poses['trunk'][:3, 3]
    half = 0.3
    ax.set_xlim(c[0] - half, c[0] + half)
    ax.set_ylim(c[1] - half, c[1] + half)
    ax.set_zlim(c[2] - half, c[2] + half)
    ax.set_box_aspect((1, 1, 1))
    ax.view_init(elev=20, azim=-40)
    ax.set_xlabel('x [m]', fontsize=8)
    ax.set_ylabel('y [m]', fontsize=8)
    ax.set_zlabel('z [m]', fontsize=8)
    ax.tick_params(labelsize=7)
    ax.set_title('URDF link frames from the bag\'s /tf + /tf_static (rosbags)', fontsize=10)
    fig.tight_layout()
    fig.savefig(args.out)
    print(f'wrote {args.out} (t = {sim.now():.2f} s of a scripted tripod step)')
    return 0


if __name__ == '__main__':
    sys.exit(main())
