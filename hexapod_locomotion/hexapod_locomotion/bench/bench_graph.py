"""bench_graph: the ROS graph walking the mockup in real time, driven by /cmd_vel, against the
in-process run of the same seed. A benchmark that prints figures, not a test.

Routes (``--route``):
  composed  ``hexapod_locomotion robot``: sim + model + locomotion nodes in one process, the
            controller owning the bus (the real-time route)
  dds       ``sim_node`` and ``locomotion_node`` as two processes, every parameter at its default,
            the reads and commands over DDS
  driver    ``robot hardware:=driver`` (driver + model + locomotion in one process, the controller
            running the AX-12A bus) against ``bus_emulator --backend sim`` (MuJoCo physics behind
            a pseudo-terminal, in real time): the hardware path

Each route runs ``--seconds`` of wall time from the first swing-down with every node at its default
rates; nothing is recorded. The truth (body position, foot contacts per millisecond of physics)
comes from a file the sim writes when it stops (``sim_node -p truth_out:=...``, ``bus_emulator
--truth-out``), not from topics: publishing it at 1 kHz loaded the process under test enough to
slow the composed controller from 3 to 11 ms per control step. From the truth and what a probe
receives (``/ground_detection``, ``/swing_down``; the probe also publishes ``/cmd_vel`` and is a
process of its own at nice +10, so that its ~1 kHz callbacks yield the CPU to the graph under
test): distance walked per minute of wall time and of simulated time, the swing-down read
cadence t_con (stamp gaps between consecutive reads of one femur within one swing-down, as the
controller consumed them, against L x T_com), the detection delay after the first true contact,
the swing-downs stopped "on ground" with the foot still in the air, and the CPU each process used.
The in-process reference is ``run_trial`` for the same simulated time (what ``./hexapod demo``
runs). DDS stays on loopback in its own ROS_DOMAIN_ID.
"""
from __future__ import annotations

import argparse
import math
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from types import SimpleNamespace

import numpy as np

from hexapod_model.contract import stamp_seconds

ROUTES = ('composed', 'dds', 'driver')
TRUTH_FILE = '{route}_truth.npz'    # one per route: --route all runs every route in one folder


def _truth_path(workdir: str, route: str) -> str:
    """The sim's truth log of ``route`` in ``workdir``."""
    return os.path.join(workdir, TRUTH_FILE.format(route=route))


def _exe(pkg: str, name: str) -> str:
    from ament_index_python.packages import get_package_prefix
    return os.path.join(get_package_prefix(pkg), 'lib', pkg, name)


def _cpu_s(pid: int) -> float:
    """User + system CPU seconds of a process (Linux /proc)."""
    with open(f'/proc/{pid}/stat') as f:
        fields = f.read().rsplit(')', 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf('SC_CLK_TCK')


def _processes(route: str, args, workdir: str) -> list[tuple[str, list[str]]]:
    truth = _truth_path(workdir, route)
    sim_params = [f'terrain:={args.terrain}', f'seed:={args.seed}', f'truth_out:={truth}']
    loco_params = [f'gait:={args.gait}', *args.param]
    p = lambda params: [a for x in params for a in ('-p', x)]  # noqa: E731
    if route == 'driver':
        link = os.path.join(workdir, 'ttyHEX')
        return [('bus_emulator (sim)', [_exe('hexapod_driver', 'bus_emulator'), '--backend', 'sim',
                                        '--terrain', args.terrain, '--terrain-seed', str(args.seed), '--link', link,
                                        '--truth-out', truth]),
                ('robot (driver+model+locomotion)', [_exe('hexapod_locomotion', 'robot'), '--ros-args',
                                                     *p(['hardware:=driver', f'device:={link}'] + loco_params)])]
    if route == 'composed':
        return [('robot (sim+model+locomotion)', [_exe('hexapod_locomotion', 'robot'), '--ros-args',
                                                  *p(sim_params + loco_params)])]
    return [('sim_node', [_exe('hexapod_sim', 'sim_node'), '--ros-args', *p(sim_params)]),
            ('locomotion_node', [_exe('hexapod_locomotion', 'locomotion_node'), '--ros-args', *p(loco_params)])]


class _Probe:
    """Collects what the figures need, in this process (the graph under test records nothing)."""

    def __init__(self, node):
        from hexapod_model.contract import GROUND_DETECTION, SWING_DOWN
        from hexapod_msgs.msg import LegGroundDetection, SwingDownStart
        self.pose, self.contacts, self.reads, self.swings = [], [], {}, []
        self.first_swing = threading.Event()
        node.create_subscription(LegGroundDetection, GROUND_DETECTION, self._read, 1000)
        node.create_subscription(SwingDownStart, SWING_DOWN, self._swing, 100)
        self.measuring = False

    def _swing(self, m):
        self.first_swing.set()
        if self.measuring:
            self.swings.append(stamp_seconds(m.header.stamp))

    def _read(self, m):
        if self.measuring:
            self.reads.setdefault((round(stamp_seconds(m.swing_start), 6), m.leg), []).append(
                (stamp_seconds(m.header.stamp), bool(m.stopped), int(m.stop_reason)))


PROBE_NICE = 10       # the probe is measuring equipment: it yields the CPU to the graph under test


def probe_main(out: str, domain_id: int, vx: float) -> int:
    """The probe process: publishes /cmd_vel, waits for the first swing-down, writes ``out``.started
    (the window's wall-clock start), collects until SIGINT/SIGTERM, then writes ``out`` (JSON).

    It runs apart from the benchmark's main process, at nice +10, so that on a 2-core machine the
    ~1 kHz /ground_detection callbacks it needs do not take the CPU from the graph it measures
    (the graph's processes run at the user's niceness)."""
    import json

    import rclpy
    from geometry_msgs.msg import Twist
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.signals import SignalHandlerOptions
    os.nice(PROBE_NICE)
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    ctx = rclpy.context.Context()
    rclpy.init(context=ctx, domain_id=domain_id, signal_handler_options=SignalHandlerOptions.NO)
    node = rclpy.create_node('bench_graph', context=ctx)
    probe = _Probe(node)
    pub = node.create_publisher(Twist, '/cmd_vel', 10)
    tw = Twist()
    tw.linear.x = vx
    node.create_timer(0.1, lambda: pub.publish(tw))
    ex = SingleThreadedExecutor(context=ctx)
    ex.add_node(node)
    threading.Thread(target=ex.spin, daemon=True).start()
    try:
        while not probe.first_swing.wait(0.1):
            if stop.is_set():
                return 1
        probe.measuring = True
        window = [time.time(), math.nan]
        with open(out + '.started', 'w') as f:
            f.write(repr(window[0]))
        stop.wait()
        probe.measuring = False
        window[1] = time.time()
        with open(out + '.part', 'w') as f:
            json.dump({'window': window, 'swings': probe.swings,
                       'reads': [[start, leg, rs] for (start, leg), rs in probe.reads.items()]}, f)
        os.replace(out + '.part', out)
        return 0
    finally:
        ex.shutdown()
        node.destroy_node()
        rclpy.shutdown(context=ctx)


def _wait_for(path: str, proc: subprocess.Popen, timeout_s: float) -> bool:
    t_end = time.monotonic() + timeout_s
    while time.monotonic() < t_end and proc.poll() is None:
        if os.path.exists(path):
            return True
        time.sleep(0.1)
    return os.path.exists(path)


def run_route(route: str, args, workdir: str) -> dict:
    import json
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST', ROS_DOMAIN_ID=str(args.domain_id),
               PYTHONUNBUFFERED='1')
    logs = [open(os.path.join(workdir, f'{route}_{i}.log'), 'w+') for i in range(3)]
    procs = []
    probe_out = os.path.join(workdir, f'{route}_probe.json')
    truth_file = _truth_path(workdir, route)
    for stale in (probe_out, probe_out + '.started', truth_file):     # a kept folder of an earlier run
        if os.path.exists(stale):
            os.remove(stale)
    probe_proc = None
    ended = None
    try:
        for i, (name, cmd) in enumerate(_processes(route, args, workdir)):
            procs.append((name, subprocess.Popen(cmd, env=env, stdout=logs[i], stderr=subprocess.STDOUT)))
            if route == 'driver' and i == 0:                 # the robot opens the emulator's port at start
                _wait_for(os.path.join(workdir, 'ttyHEX'), procs[0][1], 60)
        probe_proc = subprocess.Popen([sys.executable, '-m', 'hexapod_locomotion.bench.bench_graph', '--probe-out', probe_out,
                                       '--domain-id', str(args.domain_id), '--vx', repr(args.vx)],
                                      env=env, stdout=logs[2], stderr=subprocess.STDOUT)
        if not _wait_for(probe_out + '.started', probe_proc, 120):
            raise RuntimeError(f'{route}: no swing-down within 120 s; logs in {workdir}')
        cpu0 = {name: _cpu_s(p.pid) for name, p in procs}
        t0 = time.monotonic()
        cpu = {}
        while time.monotonic() - t0 < args.seconds and ended is None:
            for name, p in procs:
                if p.poll() is None:
                    cpu[name] = _cpu_s(p.pid) - cpu0[name]
                else:                 # the route failed: report what it did until then, and why
                    ended = f'{name} ended with rc {p.returncode} after {time.monotonic() - t0:.0f} s: ' + \
                        _last_error(logs[[n for n, _ in procs].index(name)])
            time.sleep(0.5)
        probe_proc.send_signal(signal.SIGINT)
        probe_proc.wait(30)
        wall = time.monotonic() - t0
        cpu = {name: v / wall for name, v in cpu.items()}
    finally:
        if probe_proc is not None and probe_proc.poll() is None:
            probe_proc.kill()
        for _, p in reversed(procs):        # the controller before the bus it drives (torque off)
            if p.poll() is None:
                p.send_signal(signal.SIGINT)
            try:
                p.wait(30)
            except subprocess.TimeoutExpired:
                p.kill()
    if not os.path.exists(probe_out):
        raise RuntimeError(f'{route}: the probe wrote nothing; logs in {workdir}')
    with open(probe_out) as f:
        data = json.load(f)
    # what the probe process saw; _truth_from_file adds pose and contacts
    probe = SimpleNamespace(swings=data['swings'],
                            reads={(start, leg): [tuple(r) for r in rs] for start, leg, rs in data['reads']})
    # the driver stamps its reads with the wall clock, the sim with simulated time
    sim_s = _truth_from_file(probe, truth_file, data['window'], wall_stamps=route == 'driver')
    out = figures(probe, args.gait)
    out['sim_s'] = sim_s
    out.update(route=route, wall_s=wall, cpu=cpu, ended=ended)
    return out


def _truth_from_file(probe: _Probe, path: str, window, wall_stamps: bool) -> float:
    """Fill the probe's pose and contacts from the truth file of the sim or the emulator
    (:mod:`hexapod_sim.physics.truth_log`), on the clock the reads are stamped with; returns the simulated
    seconds within the wall-clock window."""
    from hexapod_sim.physics.plant import SimError
    from hexapod_sim.physics.truth_log import load_truth
    if not os.path.exists(path):
        raise RuntimeError(f'the sim wrote no truth file ({path})')
    try:
        truth = load_truth(path)
    except SimError as exc:
        raise RuntimeError(str(exc)) from None
    sel = truth[(truth[:, 0] >= window[0]) & (truth[:, 0] <= window[1])]
    if len(sel) < 2:
        raise RuntimeError(f'the truth file holds {len(sel)} samples in the measured window')
    t = sel[:, 0] if wall_stamps else sel[:, 1]
    probe.pose = list(zip(t, sel[:, 2]))
    probe.contacts = [(ti, [bool(c) for c in row[5:11]]) for ti, row in zip(t, sel)]
    return float(sel[-1, 1] - sel[0, 1])


def _ros_param(text: str) -> str:
    name, sep, value = text.partition(':=')
    if not sep or not name or not value:
        raise argparse.ArgumentTypeError(f'expected NAME:=VALUE, got {text!r}')
    return text


def _last_error(log) -> str:
    log.flush()
    log.seek(0)
    lines = [ln.strip() for ln in log if 'ERROR' in ln or 'Error' in ln]
    return lines[-1] if lines else '(no error logged)'



def figures(probe: _Probe, gait: str) -> dict:
    """Distance, t_con and detection delay from what the probe saw."""
    from hexapod_locomotion.core.gait import get_gait
    from hexapod_model.description import load_robot
    t_com = load_robot().bus.t_com_s
    L = len(get_gait(gait).swing_legs(0))
    gaps, delays = [], []
    contact_stops = premature = 0
    c_t = np.array([c[0] for c in probe.contacts])
    c_in = np.array([c[1] for c in probe.contacts]) if probe.contacts else np.zeros((0, 6), bool)
    for (start, leg), rs in probe.reads.items():
        rs.sort()
        gaps.extend(np.diff([r[0] for r in rs]))
        stop = next((r for r in rs if r[1]), None)
        if stop is None or stop[2] != 1 or not len(c_t):
            continue
        contact_stops += 1
        sel = (c_t >= start) & (c_t <= stop[0] + 1e-9) & c_in[:, leg - 1]
        if np.any(sel):
            delays.append(stop[0] - c_t[np.flatnonzero(sel)[0]])
        else:                  # stopped "on ground" with the foot still in the air
            premature += 1
    pose = probe.pose
    return {'distance_m': pose[-1][1] - pose[0][1] if len(pose) > 1 else 0.0,
            'sim_s': pose[-1][0] - pose[0][0] if len(pose) > 1 else 0.0,
            't_con_nominal_s': L * t_com, 'gaps_s': np.array(gaps), 'delays_s': np.array(delays),
            'swing_downs': len(probe.swings), 'contact_stops': contact_stops, 'premature': premature}


def in_process(args, sim_s: float) -> dict:
    from hexapod_locomotion.trials.trial_runner import TrialConfig, run_trial
    res = run_trial(TrialConfig(gait=args.gait, terrain=args.terrain, seed=args.seed, duration_s=sim_s,
                                vx_mps=args.vx))
    d = res.detection or {}
    return {'distance_m': res.distance_m, 'sim_s': res.sim_time_s,
            'delay_median_s': (d.get('delay_s') or {}).get('median', math.nan)}


def _pct(a, q):
    return float(np.percentile(a, q)) if len(a) else math.nan


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    if argv[:1] == ['--probe-out']:           # the probe process that run_route starts
        pa = argparse.ArgumentParser(prog='bench_graph probe')
        pa.add_argument('--probe-out', required=True)
        pa.add_argument('--domain-id', type=int, required=True)
        pa.add_argument('--vx', type=float, required=True)
        a = pa.parse_args(argv)
        return probe_main(a.probe_out, a.domain_id, a.vx)
    from hexapod_model.cli_common import fail, finite_float, make_parser, positive_float
    ap = make_parser('bench_graph', __doc__, formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    ap.add_argument('--route', choices=ROUTES + ('all',), default='all', help='which graph to run')
    ap.add_argument('--seconds', type=positive_float, default=60.0,
                    help='wall time per route, from the first swing-down')
    ap.add_argument('--gait', default='tripod', help='gait of the controller')
    ap.add_argument('--terrain', default='mockup', help='terrain of the sim')
    ap.add_argument('--seed', type=int, default=0, help='terrain seed (the in-process reference uses it too)')
    ap.add_argument('--vx', type=finite_float, default=0.05, help='/cmd_vel forward speed [m/s]')
    ap.add_argument('--domain-id', type=int, default=86, help='ROS_DOMAIN_ID of the graph (loopback only)')
    ap.add_argument('--keep', metavar='DIR', help='keep the node logs in DIR')
    ap.add_argument('-p', '--param', action='append', default=[], metavar='NAME:=VALUE', type=_ros_param,
                    help='a parameter for the node that runs the controller (robot or locomotion_node), '
                         'e.g. -p real_time_factor:=0.0; repeatable')
    args = ap.parse_args(argv)
    from hexapod_locomotion.core.gait import GaitError, get_gait
    try:
        get_gait(args.gait)
    except GaitError as exc:
        fail(ap, str(exc))
    os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    workdir = args.keep or tempfile.mkdtemp(prefix='bench_graph_')
    os.makedirs(workdir, exist_ok=True)
    routes = ROUTES if args.route == 'all' else (args.route,)
    print(f'bench_graph: {args.gait} on {args.terrain} (seed {args.seed}), /cmd_vel x = {args.vx} m/s, '
          f'{args.seconds:g} s of wall time per route, {os.cpu_count()} CPU(s), ROS_DOMAIN_ID={args.domain_id}',
          flush=True)
    try:
        results = []
        for r in routes:
            print(f'running route {r} ...', file=sys.stderr, flush=True)
            results.append(run_route(r, args, workdir))
        print('in-process reference (run_trial, same seed and simulated time) ...', file=sys.stderr, flush=True)
        ref = in_process(args, max(r['sim_s'] for r in results))
    except RuntimeError as exc:
        print(f'bench_graph: {exc}', file=sys.stderr)
        return 1
    finally:
        if not args.keep:
            shutil.rmtree(workdir, ignore_errors=True)
    print(f'\nin-process: {ref["distance_m"]:.3f} m in {ref["sim_s"]:.1f} s simulated '
          f'({60 * ref["distance_m"] / ref["sim_s"]:.3f} m/min), detection delay median '
          f'{ref["delay_median_s"] * 1e3:.0f} ms')
    hdr = ('route', 'wall s', 'sim s', 'm/min wall', 'vs in-proc', 't_con med ms', 'p95 ms', 'L*T_com ms',
           'delay med ms', 'vs in-proc', 'stops in the air', 'CPU per process')
    print(' | '.join(hdr))
    for r in results:
        per_min = 60 * r['distance_m'] / r['wall_s']
        ref_per_min = 60 * ref['distance_m'] / ref['sim_s']
        dmed = float(np.median(r['delays_s'])) if len(r['delays_s']) else math.nan
        cpu = ', '.join(f'{k} {100 * v:.0f} %' for k, v in r['cpu'].items())
        print(' | '.join([r['route'], f'{r["wall_s"]:.0f}', f'{r["sim_s"]:.1f}', f'{per_min:.3f}',
                          f'{per_min / ref_per_min:.0%}', f'{_pct(r["gaps_s"], 50) * 1e3:.2f}',
                          f'{_pct(r["gaps_s"], 95) * 1e3:.2f}', f'{r["t_con_nominal_s"] * 1e3:.1f}',
                          f'{dmed * 1e3:.0f}', f'{dmed / ref["delay_median_s"]:.2f}x',
                          f'{r["premature"]} / {r["contact_stops"]}', cpu]))
        if r['ended']:
            print(f'  {r["route"]}: {r["ended"]}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
