"""Parameter files and launch files (``launch`` itself is not installable here, so its files are
checked by structure): each node's config/<executable>.yaml is what its schema declares, each node
starts with its file and declares exactly the file's keys, a bad start value of each node is one
line and exit code 1, and every executable, parameter file and parameter a launch file names exists
in the install space or is declared by that node."""
import ast
import os
import subprocess
from pathlib import Path

import pytest

rclpy = pytest.importorskip('rclpy')

from hexapod_driver.config import NODE as DRIVER  # noqa: E402
from hexapod_locomotion.nodes.params import NODE as LOCOMOTION  # noqa: E402
from hexapod_locomotion.nodes.params import TERRAIN_NODE  # noqa: E402
from hexapod_model.param_schema import MODEL_NODE, params_yaml  # noqa: E402
from hexapod_sim.node.params import NODE as SIM  # noqa: E402

REPO = Path(__file__).resolve().parent.parent
NODES = {n.executable: n for n in (DRIVER, SIM, MODEL_NODE, LOCOMOTION, TERRAIN_NODE)}
ROS_DECLARED = {'use_sim_time', 'start_type_description_service'}     # rclpy declares these on every node
LAUNCH_FILES = sorted((REPO / 'hexapod_locomotion' / 'launch').glob('*.launch.py'))


def install_prefix(package: str) -> Path:
    from ament_index_python.packages import get_package_prefix
    return Path(get_package_prefix(package))


def node_env():
    return dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST', PYTHONUNBUFFERED='1')


@pytest.mark.parametrize('exe', list(NODES))
def test_parameter_file_is_the_schema_and_is_installed(exe):
    node = NODES[exe]
    src = REPO / node.package / 'config' / f'{exe}.yaml'
    assert src.read_text() == params_yaml(node), f'{src} is stale: ./hexapod shell python tools/params_files.py'
    installed = install_prefix(node.package) / 'share' / node.package / 'config' / f'{exe}.yaml'
    assert installed.is_file(), installed


def _start_in_process(exe, ctx, tmp_path):
    """The node object started in ``ctx`` (whose arguments carry --params-file); (node, cleanup)."""
    if exe == 'sim_node':
        from hexapod_sim.node.sim_node import SimNode
        n = SimNode(context=ctx)
        return n, n.close
    if exe == 'model_node':
        from hexapod_model.model_node import ModelNode
        return ModelNode(context=ctx), lambda: None
    if exe == 'terrain_node':
        from hexapod_locomotion.nodes.terrain_node import TerrainNode
        return TerrainNode(context=ctx), lambda: None
    if exe == 'locomotion_node':
        from hexapod_locomotion.nodes.locomotion_node import LocomotionNode
        n = LocomotionNode(context=ctx)          # waits for a bus master in its thread; stopped below
        return n, lambda: None
    from hexapod_driver.driver_node import DriverNode
    from hexapod_driver.emulator import BusEmulator
    emu = BusEmulator().__enter__()
    try:
        n = DriverNode(context=ctx, parameter_overrides=[rclpy.parameter.Parameter('device', value=emu.port)])
    except BaseException:
        emu.__exit__(None, None, None)
        raise

    def cleanup():
        n.shutdown_bus()
        emu.__exit__(None, None, None)
    return n, cleanup


@pytest.mark.parametrize('exe', list(NODES))
def test_each_node_starts_with_its_file_and_declares_exactly_its_keys(exe, tmp_path):
    import yaml
    node = NODES[exe]
    path = install_prefix(node.package) / 'share' / node.package / 'config' / f'{exe}.yaml'
    keys = set(yaml.safe_load(path.read_text())[node.node_name]['ros__parameters'])
    assert keys == set(node.names())
    os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    ctx = rclpy.Context()
    rclpy.init(context=ctx, args=['--ros-args', '--params-file', str(path)])
    try:
        n, cleanup = _start_in_process(exe, ctx, tmp_path)
        try:
            assert n.get_name() == node.node_name
            declared = set(n.list_parameters([], 0).names) - ROS_DECLARED
            assert declared == keys
        finally:
            cleanup()
            n.destroy_node()
    finally:
        rclpy.try_shutdown(context=ctx)


BAD_START = {
    'driver_node': ('fault_policy:=hard', "parameter fault_policy: must be one of limp, recover, got 'hard'"),
    'sim_node': ('terrain:=moon', "parameter terrain: must be one of flat, blocks, stairs, rough, mockup, class_flat, "
                                  "class_rough, class_blocks, class_soft, class_slippery, course, got 'moon'"),
    'model_node': ('robot_overlays:=[7]', 'parameter robot_overlays: must be a list of strings'),
    'locomotion_node': ('t_des_s:=-0.5', 'parameter t_des_s: must be a finite number in (0, 10], got -0.5'),
    'terrain_node': ('model:=[7]', 'parameter model: must be a string'),
}


@pytest.mark.parametrize('exe', list(NODES))
def test_each_node_refuses_a_bad_start_value_in_one_line(exe):
    node = NODES[exe]
    prm, line = BAD_START[exe]
    exe_path = install_prefix(node.package) / 'lib' / node.package / exe
    r = subprocess.run([str(exe_path), '--ros-args', '-p', prm], env=node_env(), capture_output=True, text=True,
                       timeout=120)
    assert r.returncode == 1, (r.stdout, r.stderr)
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and line in lines[0], r.stderr
    assert 'Traceback' not in r.stdout + r.stderr


def test_locomotion_node_refuses_a_negative_dwell_margin_in_one_line():
    """The improved touchdown's dwell margin (dwell_epsilon_tick) is checked by the running node as
    its other parameters are: one line naming it, exit 1, before the node does anything."""
    exe_path = install_prefix('hexapod_locomotion') / 'lib' / 'hexapod_locomotion' / 'locomotion_node'
    r = subprocess.run([str(exe_path), '--ros-args', '-p', 'dwell_epsilon_tick:=-1.0'],
                       env=dict(node_env(), ROS_DOMAIN_ID='29'), capture_output=True, text=True, timeout=120)
    lines = r.stderr.strip().splitlines()
    assert r.returncode == 1, (r.stdout, r.stderr)
    assert len(lines) == 1 and lines[0].endswith('parameter dwell_epsilon_tick: must be a finite number >= 0, got -1'), r.stderr
    assert 'Traceback' not in r.stdout + r.stderr


def test_the_composed_robot_refuses_a_bad_locomotion_parameter_in_one_line():
    """The composed robot checks locomotion_node's parameters before its bus master and model node
    start (their start-up lines used to come before the refusal)."""
    prm, line = BAD_START['locomotion_node']
    exe_path = install_prefix('hexapod_locomotion') / 'lib' / 'hexapod_locomotion' / 'robot'
    r = subprocess.run([str(exe_path), '--ros-args', '-p', prm, '-p', 'terrain:=flat'],
                       env=dict(node_env(), ROS_DOMAIN_ID='28'), capture_output=True, text=True, timeout=120)
    lines = r.stderr.strip().splitlines()
    assert r.returncode == 1, (r.stdout, r.stderr)
    assert lines == [f'robot: {line}'], r.stderr
    assert r.stdout.strip() == '' and 'Traceback' not in r.stderr


UNKNOWN = [('hexapod_sim', 'sim_node', 'sim_node: parameter terain: no such parameter (did you mean terrain?)'),
           ('hexapod_locomotion', 'robot', 'robot: parameter terain: no such parameter (did you mean terrain?)'),
           ('hexapod_locomotion', 'locomotion_node', 'locomotion_node: parameter terain: no such parameter'),
           ('hexapod_model', 'model_node', 'model_node: parameter terain: no such parameter'),
           ('hexapod_model', 'robot_state', 'robot_state: parameter terain: no such parameter'),
           ('hexapod_driver', 'driver_node', '[hexapod_driver] parameter terain: no such parameter'),
           ('hexapod_locomotion', 'terrain_node', 'terrain_node: parameter terain: no such parameter')]


@pytest.mark.parametrize('package, exe, line', UNKNOWN, ids=[u[1] for u in UNKNOWN])
def test_every_node_refuses_a_parameter_it_does_not_know(package, exe, line, tmp_path):
    """A misspelled parameter used to be ignored (the robot walked on flat ground): each node refuses
    it in one line naming it and the nearest known name, exit 1, before anything starts."""
    r = subprocess.run([str(REPO / 'hexapod'), 'run', package, exe, '--ros-args', '-p', 'terain:=mockup'],
                       env=dict(node_env(), ROS_DOMAIN_ID='25'), capture_output=True, text=True, timeout=120,
                       cwd=tmp_path, stdin=subprocess.DEVNULL)
    # the node's own lines (./hexapod may first bring the workspace up to date: its '[hexapod] ...' and
    # colcon's lines come before)
    setup = ('[hexapod] ', 'Starting >>> ', 'Finished <<< ', 'Summary: ')
    lines = [ln for ln in r.stderr.strip().splitlines() if ln.strip() and not ln.startswith(setup)]
    assert r.returncode == 1, (r.stdout, r.stderr)
    assert len(lines) == 1 and lines[0].startswith(line), r.stderr
    assert 'Traceback' not in r.stdout + r.stderr and list(tmp_path.iterdir()) == []


def test_the_composed_robot_refuses_a_parameter_without_effect_in_its_mode(tmp_path):
    """record is the sim node's: with hardware:=driver it would write nothing, silently."""
    exe_path = install_prefix('hexapod_locomotion') / 'lib' / 'hexapod_locomotion' / 'robot'
    r = subprocess.run([str(exe_path), '--ros-args', '-p', 'hardware:=driver', '-p', f'record:={tmp_path / "b"}'],
                       env=dict(node_env(), ROS_DOMAIN_ID='24'), capture_output=True, text=True, timeout=120)
    assert r.returncode == 1, (r.stdout, r.stderr)
    assert r.stderr.strip().splitlines() == [
        'robot: parameter record: a sim_node parameter, no effect with hardware:=driver'], r.stderr
    assert list(tmp_path.iterdir()) == []


def test_the_composed_robot_refuses_a_file_entry_its_node_does_not_declare(tmp_path):
    """A parameter file addresses each node by name: an entry its node does not declare is refused,
    also when another composed node declares that name."""
    f = tmp_path / 'p.yaml'
    f.write_text('model_node:\n  ros__parameters:\n    gait: tetrapod\n')
    exe_path = install_prefix('hexapod_locomotion') / 'lib' / 'hexapod_locomotion' / 'robot'
    r = subprocess.run([str(exe_path), '--ros-args', '--params-file', str(f)],
                       env=dict(node_env(), ROS_DOMAIN_ID='24'), capture_output=True, text=True, timeout=120)
    assert r.returncode == 1, (r.stdout, r.stderr)
    assert r.stderr.strip().splitlines() == ['robot: parameter gait: model_node has no such parameter (--help lists them)'], \
        r.stderr


@pytest.mark.parametrize('exe', ['robot', 'locomotion_node'])
def test_a_huge_duration_is_refused_up_front_with_its_range(exe):
    """t_des_s:=1e9 used to be accepted and the controller died at the first /cmd_vel; the schema bounds
    every gait-cycle duration, so the node refuses it in one line naming the value and the range."""
    exe_path = install_prefix('hexapod_locomotion') / 'lib' / 'hexapod_locomotion' / exe
    r = subprocess.run([str(exe_path), '--ros-args', '-p', 't_des_s:=1e9'],
                       env=dict(node_env(), ROS_DOMAIN_ID='26'), capture_output=True, text=True, timeout=120)
    lines = r.stderr.strip().splitlines()
    assert r.returncode == 1, (r.stdout, r.stderr)
    assert lines == [f'{exe}: parameter t_des_s: must be a finite number in (0, 10], got 1e+09'], r.stderr
    assert 'Traceback' not in r.stdout + r.stderr


@pytest.mark.parametrize('package, exe', [('hexapod_sim', 'sim_node'), ('hexapod_locomotion', 'robot')])
def test_a_bag_that_cannot_be_created_is_one_line(package, exe, tmp_path):
    """record:= a path no bag can be written to (root may create nearly anything, but not under /proc):
    the sim node alone and the composed robot (whose sim node records) refuse it in one line naming
    the path, before anything runs, and leave nothing behind."""
    exe_path = install_prefix(package) / 'lib' / package / exe
    r = subprocess.run([str(exe_path), '--ros-args', '-p', 'record:=/proc/no_bag_here', '-p', 'terrain:=flat'],
                       env=dict(node_env(), ROS_DOMAIN_ID='27'), capture_output=True, text=True, timeout=120,
                       cwd=tmp_path)
    lines = r.stderr.strip().splitlines()
    assert r.returncode != 0, (r.stdout, r.stderr)
    assert len(lines) == 1 and lines[0].startswith(f'{exe}: /proc/no_bag_here: ') and 'bag' in lines[0], r.stderr
    assert 'Traceback' not in r.stdout + r.stderr
    assert list(tmp_path.iterdir()) == []


# ------------------------------------------------------------------------------------ launch files
def launch_nodes(path: Path) -> list[dict]:
    """Every ``Node(...)`` of a launch file: package, executable, name, parameter files
    (``config(package, file)`` calls) and the keys of the parameter dicts, resolved through the
    module-level and function-local names the file assigns."""
    tree = ast.parse(path.read_text())
    names = {}
    for a in ast.walk(tree):
        if isinstance(a, ast.Assign) and len(a.targets) == 1 and isinstance(a.targets[0], ast.Name):
            names[a.targets[0].id] = a.value
    out = []
    for call in ast.walk(tree):
        if not (isinstance(call, ast.Call) and getattr(call.func, 'id', None) == 'Node'):
            continue
        kw = {k.arg: k.value for k in call.keywords}
        node = {k: kw[k].value for k in ('package', 'executable', 'name') if isinstance(kw.get(k), ast.Constant)}
        node['files'], node['keys'] = [], set()
        params = kw.get('parameters')
        for item in (params.elts if isinstance(params, ast.List) else []):
            if isinstance(item, ast.Name):
                item = names[item.id]
            if isinstance(item, ast.Call) and getattr(item.func, 'id', None) == 'config':
                node['files'].append(tuple(a.value for a in item.args))
            elif isinstance(item, ast.Dict):
                node['keys'] |= {k.value for k in item.keys}
            else:
                raise AssertionError(f'{path.name}: cannot read parameter entry {ast.dump(item)}')
        out.append(node)
    return out


def test_there_are_a_robot_and_a_simulation_launch_file_and_they_are_installed():
    assert [p.name for p in LAUNCH_FILES] == ['robot.launch.py', 'sim.launch.py']
    share = install_prefix('hexapod_locomotion') / 'share' / 'hexapod_locomotion' / 'launch'
    for p in LAUNCH_FILES:
        assert (share / p.name).is_file(), share / p.name
    execs = {p.name: sorted(n['executable'] for n in launch_nodes(p)) for p in LAUNCH_FILES}
    # the composed robot (the default route) and the same nodes as separate processes
    assert execs == {'robot.launch.py': ['driver_node', 'locomotion_node', 'model_node', 'robot'],
                     'sim.launch.py': ['locomotion_node', 'model_node', 'robot', 'sim_node']}


def _members(launch: Path) -> list:
    """The node specs the composed ``robot`` runs in one process in this launch file."""
    master = DRIVER if launch.name == 'robot.launch.py' else SIM
    return [master, MODEL_NODE, LOCOMOTION]


@pytest.mark.parametrize('launch', LAUNCH_FILES, ids=lambda p: p.name)
def test_launch_file_names_installed_executables_files_and_declared_parameters(launch):
    import yaml

    from hexapod_locomotion.nodes.params import ComposedParams
    from hexapod_model.param_schema import specs as schema_specs
    nodes = launch_nodes(launch)
    assert nodes
    for n in nodes:
        if n['executable'] == 'robot':           # one process, each node under its own name
            specs = _members(launch)
            assert n['package'] == 'hexapod_locomotion' and 'name' not in n, n
            declared = set().union(*(set(s.names()) for s in specs)) | set(schema_specs(ComposedParams))
        else:
            specs = [NODES[n['executable']]]
            assert n['package'] == specs[0].package and n['name'] == specs[0].node_name, n
            declared = set(specs[0].names())
        exe = install_prefix(n['package']) / 'lib' / n['package'] / n['executable']
        assert exe.is_file() and os.access(exe, os.X_OK), exe
        assert n['files'] == [(s.package, f'{s.executable}.yaml') for s in specs], n
        for (pkg, file), spec in zip(n['files'], specs):
            path = install_prefix(pkg) / 'share' / pkg / 'config' / file
            assert path.is_file(), path
            assert spec.node_name in yaml.safe_load(path.read_text()), f'{path} does not address {spec.node_name}'
        undeclared = n['keys'] - declared - ROS_DECLARED
        assert not undeclared, f'{launch.name}: {n["executable"]} does not declare {sorted(undeclared)}'


def test_the_launch_files_are_python_launch_files():
    for p in LAUNCH_FILES:
        tree = ast.parse(p.read_text())
        assert any(isinstance(f, ast.FunctionDef) and f.name == 'generate_launch_description' for f in tree.body)
        compile(p.read_text(), str(p), 'exec')


def test_the_composed_robot_takes_parameters_as_the_launch_files_pass_them(tmp_path):
    """What ``launch_ros`` hands the composed ``robot`` of sim.launch.py: one --params-file per node
    (each addressing its node by name) and the launch file's dicts in a ``/**`` file: every node gets
    its parameters, the shared ones reach all, and Ctrl-C ends it cleanly."""
    import signal
    import time
    wild = tmp_path / 'launch_params.yaml'
    wild.write_text("/**:\n  ros__parameters:\n    hardware: sim\n    terrain: stairs\n    robot_overlays: ['']\n")
    files = [install_prefix(s.package) / 'share' / s.package / 'config' / f'{s.executable}.yaml'
             for s in (SIM, MODEL_NODE, LOCOMOTION)]
    cmd = [str(install_prefix('hexapod_locomotion') / 'lib' / 'hexapod_locomotion' / 'robot'), '--ros-args']
    for f in [*files, wild]:
        cmd += ['--params-file', str(f)]
    env = dict(node_env(), ROS_DOMAIN_ID=str(190 + os.getpid() % 30))
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    seen, t_end = [], time.monotonic() + 90
    try:
        for line in proc.stdout:
            seen.append(line)
            if 'serving /predict_swing_down' in ''.join(seen) and 'sim ready' in ''.join(seen):
                break
            if time.monotonic() > t_end:
                break
    finally:
        proc.send_signal(signal.SIGINT)
        rest, _ = proc.communicate(timeout=30)
    log = ''.join(seen) + rest
    assert 'sim ready: terrain=stairs' in log, log
    assert 'serving /predict_swing_down' in log, log
    assert proc.returncode == 0 and 'Traceback' not in log, log
