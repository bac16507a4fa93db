"""``./hexapod sim``: pictures and clips of the simulated robot, or the sim node.

    ./hexapod sim --render out.png [--terrain blocks] [--start-x 0.8]   PNG after settling
    ./hexapod sim --video out.gif --duration 4 [--terrain mockup]       GIF of a scripted tripod gait
    ./hexapod sim --urdf hexapod.urdf [--overlay X.yaml]                write the robot's URDF
    ./hexapod sim --mjcf out.xml [--terrain mockup]                    the generated MuJoCo model as one MJCF file
    ./hexapod sim [--terrain mockup] [--rtf 1] [--record auto]          run sim_node (ROS) instead
    ./hexapod sim --foxglove [PORT]                                     ... with a Foxglove live view

The MJCF file holds the whole scene (robot, terrain, lights, keyframe ``home``) and opens in
MuJoCo's viewer: ``python -m mujoco.viewer --mjcf out.xml``.

Rendering is offscreen on the CPU (``MUJOCO_GL=osmesa``, Debian package ``libosmesa6``).
"""
from __future__ import annotations

import os

# MuJoCo chooses its GL backend at import: headless default before anything imports mujoco.
os.environ.setdefault('MUJOCO_GL', 'osmesa')
if os.environ['MUJOCO_GL'] == 'osmesa':
    os.environ.setdefault('PYOPENGL_PLATFORM', 'osmesa')

import sys  # noqa: E402

from hexapod_model.cli_common import (  # noqa: E402
    add_overlay_option,
    finite_float,
    make_parser,
    nonnegative_float,
    nonnegative_int,
    output_file,
    param_float,
    port_number,
    positive_float,
    positive_int,
)
from hexapod_model.description import DescriptionError, load_robot  # noqa: E402
from hexapod_model.param_schema import specs  # noqa: E402
from hexapod_sim.node.live import DEFAULT_PORT as DEFAULT_LIVE_PORT  # noqa: E402
from hexapod_sim.node.params import SimParams  # noqa: E402
from hexapod_sim.physics.mjcf import write_mjcf  # noqa: E402
from hexapod_sim.physics.terrain import all_terrains  # noqa: E402


def build_parser():
    from hexapod_sim.tools.render import VIDEO_EXTENSIONS
    ap = make_parser('sim', __doc__)
    ap.add_argument('--terrain', default='flat', choices=list(all_terrains()), help='terrain')
    ap.add_argument('--seed', type=nonnegative_int, default=0, help='seed of the random terrains')
    ap.add_argument('--render', metavar='PNG', type=output_file(('.png',)),
                    help='write a picture of the robot standing on the terrain')
    ap.add_argument('--video', metavar='GIF', type=output_file(VIDEO_EXTENSIONS),
                    help='write a clip of the robot doing a scripted tripod gait')
    ap.add_argument('--urdf', metavar='URDF', type=output_file(('.urdf',)),
                    help="write the robot's URDF (from the description and --overlay files) and exit")
    ap.add_argument('--mjcf', metavar='XML', type=output_file(('.xml',)),
                    help='write the generated MuJoCo model (scene and terrain included) as one MJCF file')
    ap.add_argument('--duration', type=positive_float, default=4.0, help='clip length in simulated seconds')
    ap.add_argument('--settle', type=nonnegative_float, default=1.0,
                    help='simulated seconds to stand before the picture is taken')
    ap.add_argument('--start-x', type=finite_float, default=0.0, help='start position along x [m]')
    ap.add_argument('--start-y', type=finite_float, default=0.0, help='start position along y [m]')
    add_overlay_option(ap)
    ap.add_argument('--width', type=positive_int, default=None, help='image width in pixels (default: 960 PNG, 480 GIF)')
    ap.add_argument('--height', type=positive_int, default=None, help='image height in pixels (default: 720 PNG, 360 GIF)')
    ap.add_argument('--azimuth', type=finite_float, default=140.0, help='camera azimuth [deg]')
    ap.add_argument('--elevation', type=finite_float, default=-25.0, help='camera elevation [deg]')
    ap.add_argument('--distance', type=positive_float, default=0.9, help='camera distance from the trunk [m]')
    node = ap.add_argument_group('sim node (when none of --render, --video, --urdf, --mjcf is given)')
    spec = specs(SimParams)          # the node's parameters these options set: their declarations
    node.add_argument('--rtf', type=param_float(spec['real_time_factor']), default=spec['real_time_factor'].default,
                      help=f"sim_node's real_time_factor: {spec['real_time_factor'].description}")
    node.add_argument('--lockstep', action='store_true', help=f"sim_node's lockstep: {spec['lockstep'].description}")
    node.add_argument('--record', default=spec['record'].default, help=f"sim_node's record: {spec['record'].description}")
    node.add_argument('--foxglove', metavar='PORT', nargs='?', type=port_number, const=DEFAULT_LIVE_PORT,
                      help=f'serve a Foxglove live view on ws://127.0.0.1:PORT (default {DEFAULT_LIVE_PORT})')
    node.add_argument('--t-com', type=positive_float, default=None,
                      help='duration of one read [s] (default: the description\'s bus.t_com_s; 0.016 stock USB)')
    return ap


def main(argv=None) -> int:
    ap = build_parser()
    args = ap.parse_args(argv)
    if args.urdf is not None:
        return _write_urdf(ap, args)
    if args.video is not None:          # refused before anything is written or simulated
        from hexapod_sim.tools.render import VIDEO_FPS, RenderError, check_video_memory
        try:
            check_video_memory(args.duration, VIDEO_FPS, args.width or 480, args.height or 360)
        except RenderError as exc:
            print(f'{ap.prog}: error: {exc}', file=sys.stderr)
            return 2
    if args.render is None and args.video is None and args.mjcf is None:
        from hexapod_sim.bagio.recorder import RecorderError, check_bag_dir, resolve_bag_dir
        try:                  # a bad overlay or bag place is named here, in this command's words, before the node starts
            load_robot(overlays=args.overlay)
            if args.record:
                check_bag_dir(resolve_bag_dir(args.record))
        except (DescriptionError, RecorderError) as exc:
            print(f'{ap.prog}: error: {exc}', file=sys.stderr)
            return 2
        from hexapod_sim.node import sim_node
        ros = ['sim', '--ros-args', '-p', f'terrain:={args.terrain}', '-p', f'seed:={args.seed}',
               '-p', f'real_time_factor:={float(args.rtf)}', '-p', f'lockstep:={str(args.lockstep).lower()}',
               '-p', f'start_x_m:={float(args.start_x)}', '-p', f'start_y_m:={float(args.start_y)}']
        if args.record:
            ros += ['-p', f'record:={args.record}']
        if args.t_com is not None:
            ros += ['-p', f't_com_s:={float(args.t_com)}']
        if args.foxglove is not None:
            ros += ['-p', 'foxglove:=true', '-p', f'foxglove_port:={args.foxglove}']
        if args.overlay:
            ros += ['-p', 'robot_overlays:=[' + ','.join(f'"{p}"' for p in args.overlay) + ']']
        sim_node.main(ros)
        return 0

    from hexapod_sim.physics.plant import HexapodSim, SimError
    from hexapod_sim.tools.render import RenderError, record_video, render_png
    try:
        robot = load_robot(overlays=args.overlay)
        if args.mjcf:
            out = write_mjcf(robot, args.mjcf, terrain=args.terrain, seed=args.seed,
                             start_xy_m=(args.start_x, args.start_y), overlays=args.overlay)
            print(f'wrote {out} (terrain {args.terrain}, seed {args.seed}); view it with '
                  f'python -m mujoco.viewer --mjcf {out}')
        camera = dict(distance=args.distance, azimuth=args.azimuth, elevation=args.elevation)
        if args.render:
            sim = HexapodSim(robot, terrain=args.terrain, seed=args.seed, start_xy_m=(args.start_x, args.start_y))
            sim.step(args.settle)
            out = render_png(sim, args.render, width=args.width or 960, height=args.height or 720, **camera)
            print(f'wrote {out} (terrain {args.terrain}, t={sim.now():.2f} s)')
        if args.video:
            sim = HexapodSim(robot, terrain=args.terrain, seed=args.seed, start_xy_m=(args.start_x, args.start_y))
            out = record_video(sim, args.video, args.duration, width=args.width or 480,
                               height=args.height or 360, **camera)
            pos, _ = sim.body_pose()
            print(f'wrote {out} ({args.duration:g} s of a scripted tripod gait on {args.terrain}; '
                  f'trunk moved to x={pos[0]:.3f} m)')
    except (RenderError, SimError, DescriptionError, ValueError, OSError) as exc:
        print(f'{ap.prog}: error: {exc}', file=sys.stderr)
        return 2
    return 0


def _write_urdf(ap, args) -> int:
    from hexapod_model.urdf import write_urdf
    if args.render or args.video:
        ap.error('--urdf writes the URDF only; give --render/--video in another call')
    try:
        out = write_urdf(load_robot(overlays=args.overlay), args.urdf)
    except DescriptionError as exc:
        print(f'{ap.prog}: error: {exc}', file=sys.stderr)
        return 2
    except OSError as exc:
        print(f'{ap.prog}: error: cannot write {args.urdf}: {exc.strerror or exc}', file=sys.stderr)
        return 2
    extra = f' with {len(args.overlay)} overlay(s)' if args.overlay else ''
    print(f'wrote {out} (URDF of the robot description{extra})')
    return 0


if __name__ == '__main__':
    sys.exit(main())
