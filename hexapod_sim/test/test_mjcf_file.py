"""`./hexapod sim --mjcf OUT.xml`: the generated model as one plain MJCF file that MuJoCo loads back
into the same model the simulator runs; the committed browsing copy is what the generator makes."""
import os
import subprocess
from pathlib import Path

import mujoco
import numpy as np
import pytest

from hexapod_model.description import load_robot
from hexapod_sim.node import cli
from hexapod_sim.physics.mjcf import mjcf_file_text
from hexapod_sim.physics.plant import HexapodSim

COMMITTED = Path(__file__).resolve().parents[1] / 'models' / 'hexapod_ax12a_mockup.xml'
REGENERATE = f'./hexapod sim --mjcf hexapod_sim/models/{COMMITTED.name} --terrain mockup'


@pytest.fixture(scope='module')
def robot():
    return load_robot()


def _same_model(a: mujoco.MjModel, b: mujoco.MjModel) -> None:
    for n in ('nbody', 'njnt', 'nq', 'nv', 'nu', 'ngeom', 'nsite', 'nhfield', 'nkey', 'nmat', 'ntex'):
        assert getattr(a, n) == getattr(b, n), n
    for obj, count in ((mujoco.mjtObj.mjOBJ_BODY, a.nbody), (mujoco.mjtObj.mjOBJ_JOINT, a.njnt),
                       (mujoco.mjtObj.mjOBJ_ACTUATOR, a.nu), (mujoco.mjtObj.mjOBJ_GEOM, a.ngeom)):
        assert [mujoco.mj_id2name(a, obj, i) for i in range(count)] == \
            [mujoco.mj_id2name(b, obj, i) for i in range(count)], obj
    for field in ('body_mass', 'body_inertia', 'body_pos', 'geom_type', 'geom_size', 'geom_pos', 'jnt_range',
                  'dof_armature', 'dof_damping', 'dof_frictionloss', 'actuator_ctrlrange', 'key_qpos',
                  'hfield_data'):
        np.testing.assert_allclose(getattr(a, field), getattr(b, field), rtol=0, atol=1e-12, err_msg=field)
    assert a.opt.timestep == b.opt.timestep
    assert np.sum(a.body_mass) == pytest.approx(np.sum(b.body_mass), abs=1e-12)


@pytest.mark.parametrize('terrain', ['mockup', 'rough'])       # boxes and stairs; a height field
def test_sim_mjcf_writes_one_file_mujoco_loads_as_the_sims_model(tmp_path, capsys, robot, terrain):
    out = tmp_path / f'{terrain}.xml'
    assert cli.main(['--mjcf', str(out), '--terrain', terrain, '--seed', '3']) == 0
    assert f'wrote {out}' in capsys.readouterr().out
    assert list(tmp_path.iterdir()) == [out]                   # one plain file, nothing beside it
    loaded = mujoco.MjModel.from_xml_path(str(out))             # what `python -m mujoco.viewer --mjcf` does
    sim = HexapodSim(robot, terrain=terrain, seed=3)
    _same_model(loaded, sim.model)
    assert loaded.nu == 18 and loaded.body('trunk').mass > 0
    assert loaded.ngeom > 1 + 18 and (terrain != 'rough' or loaded.nhfield == 1)   # the scene came along


def test_sim_mjcf_carries_overlays_and_start(tmp_path, robot):
    overlay = tmp_path / 'backlash.yaml'
    overlay.write_text("effects:\n  - {effect: backlash, joints: [leg2_tibia], params: {width_rad: 0.02}}\n")
    out = tmp_path / 'm.xml'
    assert cli.main(['--mjcf', str(out), '--overlay', str(overlay), '--start-x', '0.5']) == 0
    loaded = mujoco.MjModel.from_xml_path(str(out))
    sim = HexapodSim(load_robot(overlays=[str(overlay)]), start_xy_m=(0.5, 0.0))
    _same_model(loaded, sim.model)
    assert loaded.joint('leg2_tibia_backlash') is not None
    assert f'--overlay {overlay}' in out.read_text().splitlines()[1]


def test_committed_model_is_what_the_generator_makes(robot):
    """hexapod_sim/models/ holds one generated model for browsing and diffs; it cannot go stale."""
    assert COMMITTED.read_text() == mjcf_file_text(robot, 'mockup', seed=0), f'stale: run {REGENERATE}'


def test_console_script_bad_path_is_one_line_and_writes_nothing(tmp_path):
    from ament_index_python.packages import get_package_prefix
    exe = os.path.join(get_package_prefix('hexapod_sim'), 'lib', 'hexapod_sim', 'sim')
    target = tmp_path / 'missing' / 'm.xml'
    res = subprocess.run([exe, '--mjcf', str(target)], capture_output=True, text=True, timeout=120, cwd=tmp_path)
    assert res.returncode == 2 and 'Traceback' not in res.stderr
    assert res.stderr.strip().splitlines() == [f'sim: error: argument --mjcf: {target}: directory '
                                               f'{target.parent} does not exist (see sim --help)']
    assert list(tmp_path.iterdir()) == []
