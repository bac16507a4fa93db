"""Offscreen pictures and clips of the simulated robot (MuJoCo renderer; CPU with MUJOCO_GL=osmesa).

MuJoCo picks its GL backend when it is first imported: set ``MUJOCO_GL=osmesa`` (and
``PYOPENGL_PLATFORM=osmesa``) before importing this module on a machine without a display
(``./hexapod`` and the ``sim`` console script do that).

:func:`record_video` takes the motion as a callback ``goals_at(t) -> {joint: theta}`` so the walking
controller can drive it later; :func:`scripted_tripod` is an open-loop tripod gait (inverse
kinematics of a fixed foot trajectory, no ground detection) used by default.
"""
from __future__ import annotations

import math
from pathlib import Path
from typing import Callable, Mapping

import mujoco
import numpy as np

from hexapod_model.description import JOINT_ROLES, LEGS, Robot, joint_name
from hexapod_model.kinematics import forward, inverse
from hexapod_sim.physics.plant import HexapodSim, run_trajectory

TRIPODS = ((1, 6, 3), (2, 5, 4))     # front-left, middle-right, rear-left / the other three


class RenderError(RuntimeError):
    """Offscreen rendering is unavailable (the message says how to enable it)."""


def _renderer(sim: HexapodSim, width: int, height: int) -> mujoco.Renderer:
    m = sim.model
    if width > m.vis.global_.offwidth or height > m.vis.global_.offheight:
        raise RenderError(f'image {width}x{height} exceeds the offscreen buffer '
                          f'{m.vis.global_.offwidth}x{m.vis.global_.offheight}')
    try:
        return mujoco.Renderer(m, height=height, width=width)
    except Exception as exc:        # no GL context: say how to get one
        raise RenderError(f'cannot create an offscreen OpenGL context ({exc}); run with MUJOCO_GL=osmesa '
                          'PYOPENGL_PLATFORM=osmesa and the Debian package libosmesa6 installed') from exc


def _camera(sim: HexapodSim, distance: float, azimuth: float, elevation: float) -> mujoco.MjvCamera:
    cam = mujoco.MjvCamera()
    cam.type = mujoco.mjtCamera.mjCAMERA_FREE
    pos, _ = sim.body_pose()
    cam.lookat[:] = pos
    cam.distance = distance
    cam.azimuth = azimuth
    cam.elevation = elevation
    return cam


def render_frame(sim: HexapodSim, renderer: mujoco.Renderer, distance: float = 0.9, azimuth: float = 140.0,
                 elevation: float = -25.0) -> np.ndarray:
    """One RGB image (H, W, 3) uint8 of the current state, camera looking at the trunk."""
    sim.refresh_derived()
    renderer.update_scene(sim.data, camera=_camera(sim, distance, azimuth, elevation))
    return renderer.render()


def render_png(sim: HexapodSim, path: str | Path, width: int = 960, height: int = 720, **camera) -> Path:
    """Write a PNG of the robot in its current state."""
    from PIL import Image
    r = _renderer(sim, width, height)
    try:
        img = render_frame(sim, r, **camera)
    finally:
        r.close()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(img).save(path)
    return path


VIDEO_EXTENSIONS = ('.gif',)      # what record_video and the demo's --video write (animated GIF, Pillow)
# Pillow holds every frame of a GIF (RGB at 4 bytes a pixel) until the file is written: a clip that would
# need more than this is refused before anything is simulated
MAX_VIDEO_BYTES = 4 * 2 ** 30
VIDEO_FPS = 25.0                  # record_video's frames per simulated second


def check_video_memory(duration_s: float, fps: float, width: int, height: int) -> None:
    """Raise :class:`RenderError` when a GIF of ``duration_s`` simulated seconds at ``fps`` frames per
    second and ``width`` x ``height`` pixels would hold more than :data:`MAX_VIDEO_BYTES` in memory."""
    frames = math.floor(duration_s * fps) + 1
    need = frames * width * height * 4
    if need > MAX_VIDEO_BYTES:
        raise RenderError(f'a {duration_s:g} s GIF at {fps:g} frames/s and {width}x{height} pixels is {frames} frames, '
                          f'{need / 2 ** 30:.1f} GiB held in memory until it is written (at most '
                          f'{MAX_VIDEO_BYTES / 2 ** 30:g} GiB): make it shorter or smaller')


def record_video(sim: HexapodSim, path: str | Path, duration_s: float,
                 goals_at: Callable[[float], Mapping[str, float]] | None = None, fps: float = VIDEO_FPS,
                 width: int = 480, height: int = 360, **camera) -> Path:
    """Run ``sim`` for ``duration_s`` driven by ``goals_at(t)`` (default: :func:`scripted_tripod`)
    and write an animated GIF with ``fps`` frames per simulated second."""
    from PIL import Image
    if duration_s <= 0 or fps <= 0:
        raise ValueError(f'duration_s and fps must be > 0, got {duration_s!r}, {fps!r}')
    check_video_memory(duration_s, fps, width, height)
    goals_at = goals_at or scripted_tripod(sim.robot)
    r = _renderer(sim, width, height)
    frames = []
    try:
        frames.append(Image.fromarray(render_frame(sim, r, **camera)))
        run_trajectory(sim, goals_at, duration_s, period_s=1.0 / fps,
                       on_period=lambda s: frames.append(Image.fromarray(render_frame(s, r, **camera))))
    finally:
        r.close()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    frames[0].save(path, save_all=True, append_images=frames[1:], duration=int(round(1000 / fps)), loop=0)
    return path


def scripted_tripod(robot: Robot, stride_m: float = 0.04, lift_m: float = 0.035, period_s: float = 1.2,
                    settle_s: float = 0.5) -> Callable[[float], dict[str, float]]:
    """Open-loop tripod gait along +x: goals as a function of time (no feedback, for pictures).

    Each tripod swings its feet forward by ``stride_m`` on a half-sine arc of height ``lift_m``
    while the other pushes back; the first ``settle_s`` holds the default stance.
    """
    home = {leg: forward(robot, leg, robot.default_stance_rad) for leg in LEGS}

    def foot(leg: int, phase: float) -> np.ndarray:
        # phase in [0, 1): first half swing (forward, lifted), second half stance (backward)
        p = home[leg].copy()
        if phase < 0.5:
            s = phase / 0.5
            p[0] += stride_m * (s - 0.5)
            p[2] += lift_m * math.sin(math.pi * s)
        else:
            s = (phase - 0.5) / 0.5
            p[0] += stride_m * (0.5 - s)
        return p

    def goals_at(t: float) -> dict[str, float]:
        out = {}
        tt = max(t - settle_s, 0.0)
        ramp = min(tt / period_s, 1.0)              # grow the stride during the first cycle
        for g, legs in enumerate(TRIPODS):
            phase = (tt / period_s + 0.5 * g) % 1.0
            for leg in legs:
                target = home[leg] + ramp * (foot(leg, phase) - home[leg])
                th = inverse(robot, leg, target)
                for role, v in zip(JOINT_ROLES, th):
                    out[joint_name(leg, role)] = float(v)
        return out

    return goals_at
