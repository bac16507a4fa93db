"""Hard kills of recording processes: are the bags they leave readable, and how much do they lose?

    ./hexapod run hexapod_sim bench_kills [--kills 20] [--seed 0] [--targets sim,robot,demo]
                                          [--modes process,group,power] [--out DIR] [--tools]

Each kill starts one recording, ``sim`` (``sim_node -p record:=BAG``), ``robot`` (the composed
robot, ``-p record:=BAG``, walking on a ``/cmd_vel`` this command publishes) or ``demo``
(``demo --duration 60 --record BAG``), waits a seeded random time and kills it:

- ``process``: SIGKILL of the process;
- ``group``: SIGKILL of its whole process group (what a terminal's kill of the job does);
- ``power``: SIGKILL of every process it started, the bag's writer process included (a power
  cut: nothing runs after it). The bag is then unfinished; ``reindex`` rebuilds it.

The nodes run on their own ROS domain (``--domain``, loopback only). The sim time at the kill comes
from ``/clock`` (sim and robot): the processes to be killed are stopped (SIGSTOP) first, the last
``/clock`` received is then the sim time they had reached, and data lost = that time minus the
bag's last log time (both sim time). The demo, which publishes no ``/clock``, keeps the sim time it has
reached in a file (``--clock-file``, :mod:`hexapod_sim.bagio.clock_file`), read the same way once it is
stopped; its bag is also compared with the bag of an uncut run of the same demo (deterministic): it must
hold exactly the uncut run's messages up to its end (:func:`prefix_check`).

Per bag: whether this project's reader and ``rosbags`` open it (as left behind, and after
``reindex`` if it was needed), its sim time span, the data lost, and with ``--tools`` whether
``analyse``, ``discrepancy`` and ``replay`` run on it with at most one warning line.
"""
from __future__ import annotations

import argparse
import os
import random
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
import warnings
from dataclasses import dataclass, field
from pathlib import Path

from hexapod_sim.bagio import BagError, BagReader, BagWarning
from hexapod_sim.bagio.clock_file import read_clock_file
from hexapod_sim.bagio.repair import reindex_bag

TARGETS = ('sim', 'robot', 'demo')
MODES = ('process', 'group', 'power')


def executable(package: str, name: str) -> str:
    """The installed console script (what ``ros2 run`` starts), found through AMENT_PREFIX_PATH."""
    for prefix in os.environ.get('AMENT_PREFIX_PATH', '').split(os.pathsep):
        exe = Path(prefix) / 'lib' / package / name
        if exe.is_file():
            return str(exe)
    raise SystemExit(f'bench_kills: {package} {name} is not installed (run ./hexapod build)')


def command(target: str, bag: Path) -> list[str]:
    if target == 'sim':
        return [executable('hexapod_sim', 'sim_node'), '--ros-args', '-p', f'record:={bag}']
    if target == 'robot':
        return [executable('hexapod_locomotion', 'robot'), '--ros-args', '-p', f'record:={bag}']
    return [executable('hexapod_locomotion', 'demo'), '--duration', '60', '--record', str(bag), '--no-progress',
            '--clock-file', str(demo_clock(bag))]


def demo_clock(bag: Path) -> Path:
    """Where the demo recording ``bag`` keeps the sim time it has reached (hexapod_sim.bagio.clock_file)."""
    return bag.with_name(bag.name + '.clock')


def pids_under(sid: int) -> list[int]:
    """Every process whose POSIX sid is ``sid`` (the command started by :func:`kill_one` with its own
    ``setsid``, and whatever it started)."""
    out = []
    for d in Path('/proc').iterdir():
        if d.name.isdigit():
            try:
                stat = (d / 'stat').read_text()
            except OSError:
                continue
            fields = stat[stat.rindex(')') + 2:].split()
            if int(fields[3]) == sid:            # field 6 of stat: the sid
                out.append(int(d.name))
    return out


class ClockWatch:
    """Keeps the latest ``/clock`` of the domain; publishes a walking ``/cmd_vel`` for the robot."""

    def __init__(self):
        import rclpy
        from geometry_msgs.msg import Twist
        from rclpy.qos import qos_profile_sensor_data
        from rosgraph_msgs.msg import Clock
        self._rclpy = rclpy
        self.ctx = rclpy.Context()
        rclpy.init(context=self.ctx)
        self.node = rclpy.create_node('bench_kills', context=self.ctx)
        self.t_s: float | None = None
        self.node.create_subscription(Clock, '/clock', self._on_clock, qos_profile_sensor_data)
        self._cmd = self.node.create_publisher(Twist, '/cmd_vel', 10)
        self._twist = Twist()
        self._twist.linear.x = 0.04
        self._twist.angular.z = 0.1
        self.node.create_timer(0.2, lambda: self._cmd.publish(self._twist))
        from rclpy.executors import SingleThreadedExecutor
        self._ex = SingleThreadedExecutor(context=self.ctx)
        self._ex.add_node(self.node)
        self._thread = threading.Thread(target=self._spin, daemon=True)
        self._thread.start()

    def _on_clock(self, msg) -> None:
        t = msg.clock.sec + msg.clock.nanosec * 1e-9
        self.t_s = t if self.t_s is None else max(self.t_s, t)

    def _spin(self) -> None:
        try:
            while self.ctx.ok():
                self._ex.spin_once(timeout_sec=0.05)
        except Exception:              # noqa: BLE001 - the context was shut down
            pass

    def reset(self) -> None:
        self.t_s = None

    def close(self) -> None:
        self._rclpy.try_shutdown(context=self.ctx)
        self._thread.join(timeout=2.0)


@dataclass
class KillResult:
    index: int
    target: str
    mode: str
    delay_s: float
    bag: Path
    t_kill_s: float | None = None         # sim time reached at the kill (/clock; the demo's clock file)
    project_ok: bool = False              # this project's reader opens the bag as left behind
    rosbags_ok: bool = False              # rosbags opens and reads it as left behind
    reindexed: bool = False               # reindex had to rebuild it
    rosbags_after_ok: bool = False        # rosbags reads it after reindex
    start_s: float = float('nan')         # the bag's log time span (sim time)
    end_s: float = float('nan')
    messages: int = 0
    prefix_ok: bool | None = None         # demo: the bag is an exact prefix of the uncut run's
    tools: dict = field(default_factory=dict)
    problem: str = ''

    @property
    def lost_s(self) -> float | None:
        return None if self.t_kill_s is None else max(0.0, self.t_kill_s - self.end_s)

    def line(self) -> str:
        lost = 'n/a (no clock)' if self.lost_s is None else f'{self.lost_s:.3f} s'
        extra = '' if self.prefix_ok is None else f', prefix of the uncut run: {"yes" if self.prefix_ok else "NO"}'
        tools = ''.join(f', {k}: {v}' for k, v in self.tools.items())
        return (f'kill {self.index:2d}: {self.target:5s} {self.mode:7s} after {self.delay_s:5.1f} s: '
                f'project reader {"ok" if self.project_ok else "NO"}, rosbags {"ok" if self.rosbags_ok else "NO"}'
                + (f' (after reindex: {"ok" if self.rosbags_after_ok else "NO"})' if self.reindexed else '')
                + f'; {self.messages} messages, sim {self.start_s:.2f}-{self.end_s:.2f} s, lost {lost}{extra}{tools}'
                + (f'; {self.problem}' if self.problem else ''))


def rosbags_read(bag: Path) -> tuple[bool, int, str]:
    """(ok, messages read, problem) with rosbags' AnyReader, every message deserialised."""
    from rosbags.highlevel import AnyReader
    try:
        n = 0
        with AnyReader([bag]) as r:
            for conn, _, raw in r.messages():
                r.deserialize(raw, conn.msgtype)
                n += 1
        return True, n, ''
    except Exception as exc:           # noqa: BLE001 - any failure is the figure we report
        return False, 0, f'rosbags: {type(exc).__name__}: {exc}'


def project_read(bag: Path) -> tuple[BagReader | None, str]:
    try:
        with warnings.catch_warnings():
            warnings.simplefilter('ignore', BagWarning)
            return BagReader(bag), ''
    except BagError as exc:
        return None, f'project reader: {exc}'


def run_tools(bag: Path, env: dict) -> dict:
    """Each tool's verdict: 'ok' (exit 0, at most one warning line, no traceback) or what went wrong."""
    out = {}
    runs = {'analyse': [executable('hexapod_locomotion', 'analyse'), str(bag)],
            'discrepancy': [executable('hexapod_sim', 'discrepancy'), str(bag)],
            'replay': [executable('hexapod_sim', 'replay'), str(bag), '--rate', '50', '--no-progress']}
    for name, cmd in runs.items():
        try:
            p = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=300)
        except subprocess.TimeoutExpired:
            out[name] = 'timeout'
            continue
        err = p.stderr
        warn_lines = [x for x in err.splitlines() if 'warning' in x.lower()]
        if 'Traceback' in err:
            out[name] = 'traceback'
        elif p.returncode != 0:
            out[name] = f'exit {p.returncode}: {err.strip().splitlines()[-1] if err.strip() else ""}'
        elif len(warn_lines) > 1:
            out[name] = f'{len(warn_lines)} warning lines'
        else:
            out[name] = 'ok'
    return out


def kill_one(i: int, target: str, mode: str, delay_s: float, bag: Path, env: dict, clock: ClockWatch | None,
             log) -> KillResult:
    res = KillResult(i, target, mode, delay_s, bag)
    if clock is not None:
        clock.reset()
    proc = subprocess.Popen(command(target, bag), env=env, stdout=subprocess.DEVNULL, stderr=log,
                            preexec_fn=os.setsid)
    sid = proc.pid
    try:
        # the recording has begun once the bag's metadata.yaml exists; the delay counts from then
        deadline = time.monotonic() + 120.0
        while not (bag / 'metadata.yaml').exists() and proc.poll() is None and time.monotonic() < deadline:
            time.sleep(0.05)
        # and once the sim's clock runs (a loaded machine may take many seconds to start the walk)
        while (clock is not None and (clock.t_s is None or clock.t_s < 0.5) and proc.poll() is None
               and time.monotonic() < deadline):
            time.sleep(0.05)
        if proc.poll() is not None:
            res.problem = f'the command ended before the kill (exit {proc.returncode})'
            return res
        time.sleep(delay_s)
        if mode == 'process':
            victims = [proc.pid]
        elif mode == 'group':
            victims = [p for p in pids_under(sid) if os.getpgid(p) == proc.pid]
        else:
            victims = pids_under(sid)
        for p in victims:                  # stop first: the last /clock is then the time they reached
            _signal(p, signal.SIGSTOP)
        if clock is not None:
            time.sleep(0.5)
            res.t_kill_s = clock.t_s
        elif target == 'demo':
            res.t_kill_s = read_clock_file(demo_clock(bag))
        for p in victims:
            _signal(p, signal.SIGKILL)
        proc.wait()
        end = time.monotonic() + 60.0      # survivors (the bag's writer) finish the bag, then end
        while pids_under(sid) and time.monotonic() < end:
            time.sleep(0.1)
        for p in pids_under(sid):        # never leave anything running
            _signal(p, signal.SIGKILL)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    reader, why = project_read(bag)
    res.project_ok = reader is not None
    ok, _, why2 = rosbags_read(bag)
    res.rosbags_ok = ok
    res.problem = '; '.join(x for x in (why, why2) if x and not (ok or reader is None))
    if not ok and reader is not None:
        try:
            r = reindex_bag(bag)
            res.reindexed = r.rebuilt
            res.rosbags_after_ok, _, why3 = rosbags_read(bag)
            res.problem = why3
            reader, _ = project_read(bag)
        except BagError as exc:
            res.problem = f'reindex: {exc}'
    if reader is not None:
        res.start_s, res.end_s, res.messages = reader.start_ns * 1e-9, reader.end_ns * 1e-9, reader.message_count
    return res


def _signal(pid: int, sig: int) -> None:
    try:
        os.kill(pid, sig)
    except ProcessLookupError:
        pass


LATE_LOGGED_S = 0.1     # the demo records IMU samples at the next probe (0.05 s), logged at their sample time


def prefix_check(bag: Path, reference: Path) -> bool:
    """True if ``bag`` holds exactly the reference bag's messages up to its end: every message of it
    is in the reference, and every reference message logged before its last ``LATE_LOGGED_S`` is in it
    (the last of those may be missing: they are recorded after messages logged later)."""
    got, _ = project_read(bag)
    ref, _ = project_read(reference)
    if got is None or ref is None:
        return False
    have = {(m.topic, m.t_ns, bytes(m.msg)) for m in got.messages(raw=True)}
    want = set()
    for m in ref.messages(raw=True, end_ns=got.end_ns + 1):
        want.add((m.topic, m.t_ns, bytes(m.msg)))
    needed = {k for k in want if k[1] <= got.end_ns - LATE_LOGGED_S * 1e9}
    return have <= want and needed <= have


def main(args=None) -> int:
    ap = argparse.ArgumentParser(prog='bench_kills', description=__doc__.split('\n\n')[0])
    ap.add_argument('--kills', type=int, default=20)
    ap.add_argument('--seed', type=int, default=0)
    ap.add_argument('--targets', default=','.join(TARGETS))
    ap.add_argument('--modes', default=','.join(MODES))
    ap.add_argument('--min-delay', type=float, default=3.0, help='earliest kill, s after the bag appears')
    ap.add_argument('--max-delay', type=float, default=20.0, help='latest kill, s after the bag appears')
    ap.add_argument('--domain', type=int, default=160, help='ROS_DOMAIN_ID of the nodes')
    ap.add_argument('--out', default=None, help='keep the bags here (default: a temporary folder)')
    ap.add_argument('--tools', action='store_true', help='also run analyse, discrepancy and replay on every bag')
    opts = ap.parse_args(sys.argv[1:] if args is None else args)
    targets = [t for t in opts.targets.split(',') if t]
    modes = [m for m in opts.modes.split(',') if m]
    bad = [t for t in targets if t not in TARGETS] + [m for m in modes if m not in MODES]
    if bad or opts.kills < 1 or not 0 <= opts.min_delay <= opts.max_delay:
        print(f'bench_kills: error: bad --targets/--modes/--kills/--min-delay/--max-delay ({bad or "values"})',
              file=sys.stderr)
        return 2
    rng = random.Random(opts.seed)
    env = dict(os.environ, ROS_DOMAIN_ID=str(opts.domain), ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST',
               PYTHONUNBUFFERED='1')
    os.environ.update(ROS_DOMAIN_ID=str(opts.domain), ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST')
    out = Path(opts.out) if opts.out else Path(tempfile.mkdtemp(prefix='bench_kills_'))
    out.mkdir(parents=True, exist_ok=True)
    clock = ClockWatch() if any(t != 'demo' for t in targets) else None
    reference = None
    results = []
    try:
        with open(out / 'processes.log', 'w') as log:
            if 'demo' in targets:
                reference = out / 'demo_uncut'
                print(f'bench_kills: uncut demo run for the prefix check -> {reference}', flush=True)
                shutil.rmtree(reference, ignore_errors=True)
                subprocess.run(command('demo', reference), env=env, stdout=subprocess.DEVNULL, stderr=log, check=True)
            for i in range(opts.kills):
                target = targets[i % len(targets)]
                mode = modes[(i // len(targets)) % len(modes)]
                delay = round(rng.uniform(opts.min_delay, opts.max_delay), 2)
                bag = out / f'kill_{i:02d}_{target}_{mode}'
                shutil.rmtree(bag, ignore_errors=True)
                res = kill_one(i, target, mode, delay, bag, env, clock if target != 'demo' else None, log)
                if target == 'demo' and res.project_ok and reference is not None:
                    res.prefix_ok = prefix_check(bag, reference)
                if opts.tools and res.project_ok:
                    res.tools = run_tools(bag, env)
                results.append(res)
                print(res.line(), flush=True)
    finally:
        if clock is not None:
            clock.close()
    readable = sum(r.project_ok and r.rosbags_ok for r in results)
    after = sum(r.project_ok and (r.rosbags_ok or r.rosbags_after_ok) for r in results)
    lost = [r.lost_s for r in results if r.lost_s is not None]
    print(f'bench_kills: {readable} of {len(results)} bags open in both readers as left behind; '
          f'{after} of {len(results)} after reindex of the unfinished ones; data lost (sim time, '
          f'{len(lost)} bags with a clock): max {max(lost) if lost else float("nan"):.3f} s, '
          f'median {sorted(lost)[len(lost) // 2] if lost else float("nan"):.3f} s; bags in {out}')
    bad_prefix = [r.index for r in results if r.prefix_ok is False]
    if bad_prefix:
        print(f'bench_kills: demo bags that are not a prefix of the uncut run: {bad_prefix}')
    return 0 if after == len(results) and not bad_prefix and all(x <= 1.0 for x in lost) else 1


if __name__ == '__main__':
    sys.exit(main())
