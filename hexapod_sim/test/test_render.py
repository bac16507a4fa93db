"""Offscreen pictures (MUJOCO_GL=osmesa) and the `sim` command line."""
import numpy as np
import pytest
from PIL import Image

from hexapod_model.description import ALL_JOINTS, JOINT_ROLES, LEGS, load_robot
from hexapod_sim.node import cli
from hexapod_sim.physics.plant import HexapodSim
from hexapod_sim.tools.render import RenderError, record_video, render_png, scripted_tripod


@pytest.fixture(scope='module')
def robot():
    return load_robot()


def _render_or_skip(fn, *a, **kw):
    try:
        return fn(*a, **kw)
    except RenderError as exc:       # no OpenGL on this machine: say so instead of failing obscurely
        pytest.skip(f'offscreen rendering unavailable: {exc}')


def test_png_shows_the_robot_on_the_terrain(robot, tmp_path):
    sim = HexapodSim(robot, terrain='blocks', start_xy_m=(0.8, 0.0))
    sim.step(0.2)
    out = _render_or_skip(render_png, sim, tmp_path / 'robot.png', width=200, height=150)
    img = np.asarray(Image.open(out).convert('RGB')).astype(float)
    assert img.shape == (150, 200, 3)
    centre = img[45:105, 60:140]                         # the camera looks at the trunk
    assert (centre.mean(axis=2) < 60).mean() > 0.05      # dark robot body in the middle
    wood = (img[..., 0] > img[..., 2] + 40)              # orange-brown blocks somewhere in view
    assert wood.mean() > 0.02


def test_video_is_driven_by_a_goal_callback(robot, tmp_path):
    sim = HexapodSim(robot, terrain='flat')
    calls = []
    gait = scripted_tripod(robot)

    def goals_at(t):
        calls.append(t)
        return gait(t)
    out = _render_or_skip(record_video, sim, tmp_path / 'clip.gif', duration_s=0.2, goals_at=goals_at, fps=25,
                          width=96, height=72)
    gif = Image.open(out)
    assert gif.n_frames == 1 + 5                          # the start plus one frame per 40 ms
    assert calls == pytest.approx(np.arange(5) * 0.04)
    assert sim.now() == pytest.approx(0.2)


def test_scripted_tripod_lifts_one_tripod_at_a_time(robot):
    g = scripted_tripod(robot, settle_s=0.0)
    from hexapod_model.kinematics import forward
    from hexapod_sim.tools.render import TRIPODS
    for t in np.linspace(1.3, 2.3, 9):                    # after the first (ramp) cycle
        goals = g(t)
        assert set(goals) == set(ALL_JOINTS)
        z = {leg: forward(robot, leg, [goals[f'leg{leg}_{r}'] for r in JOINT_ROLES])[2]
             for leg in LEGS}
        lifted = [max(z[leg] for leg in tri) - min(z.values()) > 1e-3 for tri in TRIPODS]
        assert sum(lifted) <= 1                           # never both tripods in the air


def test_cli_reports_bad_input(capsys):
    with pytest.raises(SystemExit) as e:
        cli.main(['--render', 'x.png', '--terrain', 'lava'])
    assert e.value.code == 2 and 'lava' in capsys.readouterr().err
    with pytest.raises(SystemExit) as e:
        cli.main(['--render', 'x.png', '--overlay', '/nonexistent/overlay.yaml'])
    assert e.value.code == 2 and 'overlay.yaml' in capsys.readouterr().err
