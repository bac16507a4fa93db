"""soak: the composed robot on the emulated AX-12A bus for N minutes, walking, recording, with faults
that come and go; figures as it goes and at the end, and checks (exit 1 when one fails).

Processes (each its own process group, so Ctrl-C reaches only this one, which then stops them in
order: the robot first, so that its torque-off reaches the servos, then the recorder, then the bus):

* ``bus_emulator --backend sim`` (hexapod_driver): 18 emulated AX-12A servos whose horns are the
  MuJoCo hexapod's joints, on a pseudo-terminal behind a stable symlink; it applies a seeded fault
  schedule (:mod:`hexapod_driver.emulator.fault_schedule`) once walking starts, writes each fault's
  start and end, every position its servos reported, and at exit their torque registers;
* ``robot`` with ``hardware:=driver`` (driver, model and locomotion nodes in one process) on that
  port, ``fault_policy:=recover``;
* ``record_contract`` (hexapod_sim): /joint_commands and /joint_states into a bag;
* this process: a seeded ``/cmd_vel`` that walks, turns and stops, and the monitor (``/diagnostics``,
  ``/ground_detection``, ``/bus_timing``, each process's RSS and CPU time from ``/proc``).

Checks (:mod:`hexapod_locomotion.bench.soak_checks`): RSS growth after the first minute at most
``--rss-limit-mb`` per process (runs of 3 minutes or more); the last window's control period median
and p99 within ``--period-tolerance`` of the first window's (at least two windows); every injected
fault on ``/diagnostics`` while it lasted and its recovery afterwards (fault policy ``recover``);
every position on ``/joint_states`` one a servo reported; torque off on every servo at the end; the
bag readable by ``rosbags`` with the counts its metadata promises and data up to the end.
"""
from __future__ import annotations

import json
import math
import os
import random
import signal
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from hexapod_locomotion.bench import soak_checks as sc

EXIT_OK, EXIT_CHECK_FAILED, EXIT_USAGE = 0, 1, 2
SAMPLE_PERIOD_S = 5.0                 # /proc sampling
RSS_AFTER_S = 60.0                    # RSS growth counts from here
DRIFT_MIN_S = 600.0                   # shorter runs print the control period drift, do not judge it
STARTUP_TIMEOUT_S = 120.0
FAULT_POLICY = 'recover'
PAGE = os.sysconf('SC_PAGE_SIZE')
TICKS = os.sysconf('SC_CLK_TCK')


# ----------------------------------------------------------------------------- plain helpers
def cmd_vel_schedule(seed: int, duration_s: float) -> list[tuple[float, float, float, float]]:
    """Seeded segments (start [s], vx [m/s], vy [m/s], wz [rad/s]): walks, turns, both, and stops."""
    rng = random.Random(seed + 1)
    out, t = [], 0.0
    kinds = ['walk', 'turn', 'arc', 'stop', 'walk', 'side']
    while t < duration_s:
        kind = rng.choice(kinds)
        vx = vy = wz = 0.0
        if kind in ('walk', 'arc'):
            vx = rng.uniform(0.02, 0.05)
        if kind in ('turn', 'arc'):
            wz = rng.choice((-1, 1)) * rng.uniform(0.1, 0.3)
        if kind == 'side':
            vy = rng.choice((-1, 1)) * rng.uniform(0.01, 0.03)
        out.append((t, vx, vy, wz))
        t += rng.uniform(2.0, 5.0) if kind == 'stop' else rng.uniform(5.0, 15.0)
    return out


def proc_sample(pid: int) -> tuple[float, float] | None:
    """(CPU seconds, RSS bytes) of a live process, from /proc; None when it has gone."""
    try:
        with open(f'/proc/{pid}/stat') as f:
            fields = f.read().rsplit(')', 1)[1].split()
        with open(f'/proc/{pid}/statm') as f:
            rss_pages = int(f.read().split()[1])
    except (OSError, IndexError, ValueError):
        return None
    return (int(fields[11]) + int(fields[12])) / TICKS, rss_pages * PAGE


def _first_from(items: list, time_of, t0: float, start: int) -> int:
    """The index of the first of ``items`` (in arrival order) from ``start`` on whose time is ``t0`` or later."""
    while start < len(items) and time_of(items[start]) < t0:
        start += 1
    return start


@dataclass
class Proc:
    name: str
    popen: subprocess.Popen | None
    log: Path
    samples: list[tuple[float, float, float]] = field(default_factory=list)   # (t since walk start, cpu s, rss)

    @property
    def pid(self) -> int:
        return os.getpid() if self.popen is None else self.popen.pid

    def sample(self, t: float) -> None:
        s = proc_sample(self.pid)
        if s is not None:
            self.samples.append((t, *s))


def window_length(minutes: float) -> float:
    return 300.0 if minutes >= 10 else 60.0 if minutes >= 2 else 15.0


# ----------------------------------------------------------------------------- the run
class Soak:
    def __init__(self, args, out: Path):
        from hexapod_model.description import ALL_JOINTS, load_robot
        self.args, self.out = args, out
        self.robot = load_robot()
        self.duration_s = args.minutes * 60.0
        self.window_s = window_length(args.minutes)
        self.joint_id = {bj.joint: bj.servo_id for bj in self.robot.bus.joints}
        self.all_ids = sorted(self.joint_id.values())
        self.procs: dict[str, Proc] = {}
        self.statuses: list[dict] = []
        self.reads: list[tuple[int, float, float]] = []     # /ground_detection: leg, swing start, stamp
        self._seen_reads = self._seen_statuses = 0          # where the last progress line's span began
        self.timing: list[tuple[float, int, int]] = []      # /bus_timing: t, reads, failed
        self.t_walk0 = math.nan
        self.t_walk1 = math.nan
        self.interrupted = False
        self._sigint = False        # Ctrl-C seen: raised as KeyboardInterrupt at the next check of the loops
        self.js_publishers = 0
        self.load: list[tuple[float, float]] = []           # (t since walk start, 1-min load average)
        self.ended_early = ''
        self._diag_log = open(out / 'diagnostics.jsonl', 'w', buffering=1 << 16)
        self._ALL = ALL_JOINTS

    # -- output
    def say(self, text: str) -> None:
        print(text, flush=True)
        with open(self.out / 'report.txt', 'a') as f:
            f.write(text + '\n')

    # -- processes
    def _start(self, name: str, pkg: str, exe: str, argv: list[str]) -> Proc:
        """Start the installed executable ``exe`` of ``pkg`` (as ``ros2 run`` finds it)."""
        from ament_index_python.packages import get_package_prefix
        log = self.out / f'{name}.log'
        path = os.path.join(get_package_prefix(pkg), 'lib', pkg, exe)
        popen = subprocess.Popen([sys.executable, path, *argv], stdout=open(log, 'w'), stderr=subprocess.STDOUT,
                                 env=dict(os.environ, PYTHONUNBUFFERED='1'), process_group=0)
        p = self.procs[name] = Proc(name, popen, log)
        return p

    def start_processes(self) -> None:
        from hexapod_driver import protocol as pr
        from hexapod_driver.emulator.fault_schedule import dump_schedule, random_schedule
        # The controller reads the femur and tibia of each swinging leg (the swing-down's measured start)
        # and stops when one stays silent past its read timeout (2 s): a coxa is the servo that may go
        # silent for seconds while the walk goes on.
        quiet = [bj.servo_id for bj in self.robot.bus.joints if bj.joint.endswith('coxa')]
        lo = pr.REGISTERS['min_voltage_limit'].default * pr.VOLTAGE_UNIT_V
        hi = pr.REGISTERS['max_voltage_limit'].default * pr.VOLTAGE_UNIT_V
        schedule = random_schedule(self.args.seed, self.duration_s, servo_ids=self.all_ids, quiet_ids=quiet,
                                   temperature_limit_c=self.robot.servo.shutdown_temperature_c,
                                   voltage_limits_v=(lo, hi))
        dump_schedule(schedule, self.out / 'faults.json')
        self.say(f'soak: {self.args.minutes:g} min, seed {self.args.seed}, {len(schedule)} faults scheduled, '
                 f'windows of {self.window_s:g} s, output in {self.out}')
        tty = self.out / 'tty'
        self._start('emulator', 'hexapod_driver', 'bus_emulator', ['--backend', 'sim', '--link', str(tty),
                                 '--seed', str(self.args.seed), '--fault-schedule', str(self.out / 'faults.json'),
                                 '--events-out', str(self.out / 'faults.jsonl'),
                                 '--replies-out', str(self.out / 'replies.bin')])
        self._wait(lambda: tty.is_symlink(), 60.0, 'the bus emulator\'s port')
        self._start('recorder', 'hexapod_sim', 'record_contract', ['--out', str(self.out / 'bag')])
        self._start('robot', 'hexapod_locomotion', 'robot', ['--ros-args', '-p', 'hardware:=driver',
                              '-p', f'device:={tty}', '-p', f'fault_policy:={FAULT_POLICY}'])
        self.procs['soak'] = Proc('soak', None, self.out / 'report.txt')

    def _wait(self, cond, timeout_s: float, what: str, spin=None) -> None:
        t_end = time.monotonic() + timeout_s
        while not cond():
            self._check_alive()
            if time.monotonic() > t_end:
                raise RuntimeError(f'no {what} within {timeout_s:g} s')
            if spin is not None:
                spin(0.1)
            else:
                time.sleep(0.1)

    def _on_sigint(self, _signum, _frame) -> None:
        self._sigint = True

    def _check_alive(self) -> None:
        if self._sigint:
            raise KeyboardInterrupt
        for p in self.procs.values():
            if p.popen is not None and p.popen.poll() is not None:
                tail = p.log.read_text(errors='replace').strip().splitlines()[-3:]
                raise ChildExited(f'{p.name} exited with code {p.popen.returncode}: ' + ' | '.join(tail))

    # -- ROS monitor
    def on_diagnostics(self, msg) -> None:
        t = time.time()
        for s in msg.status:
            rec = {'t': t, 'name': s.name, 'level': s.level[0] if isinstance(s.level, bytes) else int(s.level),
                   'message': s.message, 'values': {kv.key: kv.value for kv in s.values}}
            self.statuses.append(rec)
            self._diag_log.write(json.dumps(rec) + '\n')

    def on_detection(self, msg) -> None:
        from hexapod_model.contract import stamp_seconds
        self.reads.append((msg.leg, stamp_seconds(msg.swing_start), stamp_seconds(msg.header.stamp)))

    def on_timing(self, msg) -> None:
        self.timing.append((time.time(), msg.reads, msg.failed_reads))

    def run(self) -> None:
        import rclpy
        from diagnostic_msgs.msg import DiagnosticArray
        from geometry_msgs.msg import Twist
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.signals import SignalHandlerOptions

        from hexapod_model import contract
        from hexapod_msgs.msg import BusTiming, LegGroundDetection
        rclpy.init(signal_handler_options=SignalHandlerOptions.NO)      # Ctrl-C is ours: an orderly stop
        # Ctrl-C only sets a flag that the loops check: a KeyboardInterrupt raised by the default handler
        # inside rclpy's C++ (spin_once converting a callback's argument) came out as a RuntimeError
        # ("Unable to convert call argument '0' to Python object") and the run was judged ended early
        signal.signal(signal.SIGINT, self._on_sigint)
        node = rclpy.create_node('soak')
        ex = SingleThreadedExecutor()
        ex.add_node(node)
        node.create_subscription(DiagnosticArray, contract.DIAGNOSTICS, self.on_diagnostics, 100)
        node.create_subscription(LegGroundDetection, contract.GROUND_DETECTION, self.on_detection, 1000)
        node.create_subscription(BusTiming, contract.BUS_TIMING, self.on_timing, 10)
        pub = node.create_publisher(Twist, contract.CMD_VEL, 10)
        self._node = node
        spin = lambda s: ex.spin_once(timeout_sec=s)          # noqa: E731
        try:
            self.start_processes()
            self._wait(lambda: any(s['name'].endswith(': bus') for s in self.statuses), STARTUP_TIMEOUT_S,
                       'bus diagnostics from the robot', spin)
            self.procs['emulator'].popen.send_signal(signal.SIGUSR1)     # the fault schedule's clock starts
            self.t_walk0 = time.time()
            self.say(f'walking from {time.strftime("%H:%M:%S")}; the fault schedule runs')
            self._walk(pub, spin)
        except KeyboardInterrupt:
            self.interrupted = True
            self.say('soak: Ctrl-C: stopping, the report covers the run so far')
        except (ChildExited, RuntimeError) as exc:
            self.ended_early = str(exc)
            self.say(f'soak: {exc}')
        finally:
            if math.isfinite(self.t_walk0):
                self.t_walk1 = time.time()
                self._sample_all()
            try:
                pub.publish(Twist())
                spin(0.1)
            except Exception:             # noqa: BLE001 - the context may be down after Ctrl-C
                pass
            signal.signal(signal.SIGINT, signal.SIG_IGN)      # the orderly stop is not interrupted again
            self.stop_processes()
            self._diag_log.close()
            node.destroy_node()
            rclpy.try_shutdown()

    def _walk(self, pub, spin) -> None:
        from geometry_msgs.msg import Twist
        segs = cmd_vel_schedule(self.args.seed, self.duration_s)
        next_sample = next_print = next_cmd = 0.0
        progress = min(self.window_s, 60.0)
        while True:
            t = time.time() - self.t_walk0
            if t >= self.duration_s:
                return
            self._check_alive()
            if t >= next_cmd:
                _, vx, vy, wz = [s for s in segs if s[0] <= t][-1]
                msg = Twist()
                msg.linear.x, msg.linear.y, msg.angular.z = vx, vy, wz
                pub.publish(msg)
                next_cmd = t + 0.1
            if t >= next_sample:
                self._sample_all()
                next_sample = t + SAMPLE_PERIOD_S
            if t >= next_print and t > 0:
                if next_print:
                    self._progress(t, progress)
                next_print = t + progress
            spin(0.02)

    def _sample_all(self) -> None:
        from hexapod_model import contract
        try:                          # another process publishing positions on this domain would be judged too
            self.js_publishers = max(self.js_publishers, self._node.count_publishers('/' + contract.JOINT_STATES))
        except Exception:             # noqa: BLE001 - the context may be down after Ctrl-C
            pass
        t = time.time() - self.t_walk0
        for p in self.procs.values():
            p.sample(t)
        try:                          # the machine's load: the timing figures depend on it
            with open('/proc/loadavg') as f:
                self.load.append((t, float(f.read().split()[0])))
        except (OSError, ValueError, IndexError):
            pass

    def _progress(self, t: float, span: float) -> None:
        t_abs = self.t_walk0 + t
        # the progress line looks only at the last span (arrival order): a scan of every read kept so far
        # held a core for longer each minute, against the robot it measures (its p99 rose with the run)
        self._seen_reads = _first_from(self.reads, lambda r: r[2], t_abs - span, self._seen_reads)
        self._seen_statuses = _first_from(self.statuses, lambda s: s['t'], t_abs - span, self._seen_statuses)
        ts, ps = sc.control_periods(self.reads[self._seen_reads:])
        reads = sum(r for tt, r, _ in self.timing if tt >= t_abs - span)
        failed = sum(f for tt, _, f in self.timing if tt >= t_abs - span)
        period = (f'period median {np.median(ps) * 1e3:.2f} ms p99 {np.percentile(ps, 99) * 1e3:.2f} ms'
                  if len(ps) else 'no swing-down reads')
        faults = self._fault_lines()
        started = sum(1 for f in faults if f['start'] <= t_abs)
        errors = sum(1 for s in self.statuses[self._seen_statuses:] if s['level'] >= 2)
        rss = ', '.join(f'{p.name} {p.samples[-1][2] / 2**20:.0f} MB' for p in self.procs.values() if p.samples)
        self.say(f'[{t / 60:5.1f} min] {period}; {reads / span:.0f} reads/s ({failed} failed); faults started '
                 f'{started}; {errors} ERROR statuses in the last {span:g} s; RSS {rss}')

    def stop_processes(self) -> None:
        order = [('robot', signal.SIGINT, 30.0), ('recorder', signal.SIGINT, 30.0), ('emulator', signal.SIGTERM, 30.0)]
        for name, sig, timeout in order:
            p = self.procs.get(name)
            if p is None or p.popen is None:
                continue
            if p.popen.poll() is None:
                p.popen.send_signal(sig)
            try:
                p.popen.wait(timeout=timeout)
            except subprocess.TimeoutExpired:
                self.say(f'soak: {name} did not stop within {timeout:g} s of {signal.Signals(sig).name}: killed')
                p.popen.kill()
                p.popen.wait()

    # -- analysis
    def _fault_lines(self) -> list[dict]:
        path = self.out / 'faults.jsonl'
        faults: dict[int, dict] = {}
        if not path.exists():
            return []
        for line in path.read_text().splitlines():
            try:
                rec = json.loads(line)
            except json.JSONDecodeError:
                continue
            if rec.get('phase') == 'start':
                faults[rec['fault']] = dict(rec, start=rec['t'])
            elif rec.get('phase') == 'end' and rec['fault'] in faults:
                faults[rec['fault']]['end'] = rec['t']
        return [faults[k] for k in sorted(faults)]

    def _final_registers(self) -> list[dict] | None:
        path = self.out / 'faults.jsonl'
        if not path.exists():
            return None
        for line in path.read_text().splitlines():
            if '"final"' in line:
                return json.loads(line)['servos']
        return None

    def report(self) -> list[sc.Check]:
        checks: list[sc.Check] = []
        if not math.isfinite(self.t_walk0):
            self.say('soak: the robot never started walking; no figures')
            return [sc.Check('run', False, self.ended_early or 'did not start')]
        walked = self.t_walk1 - self.t_walk0
        self.say(f'\n=== soak report: {walked / 60:.1f} min of walking'
                 f'{" (interrupted)" if self.interrupted else ""}{" (ended early)" if self.ended_early else ""} ===')
        if self.ended_early:
            checks.append(sc.Check('ran to the end', False, self.ended_early))
        checks += self._process_checks(walked)
        checks += self._period_checks(walked)
        checks += self._fault_checks()
        checks += self._end_checks()
        checks += self._bag_checks()           # bag and positions
        self.say('checks:')
        for c in checks:
            self.say(f'  {"PASS" if c.ok else "FAIL"}  {c.name}: {c.detail}')
        return checks

    def _process_checks(self, walked: float) -> list[sc.Check]:
        """Each process's CPU and memory; its RSS growth after the first minute checked on long runs."""
        checks: list[sc.Check] = []
        self.say('process     CPU s/s   RSS start  RSS@1min  RSS end   growth after 1 min')
        for p in self.procs.values():
            if len(p.samples) < 2:
                continue
            (t0, c0, r0), (t1, c1, r1) = p.samples[0], p.samples[-1]
            base, growth = sc.rss_growth([(t, r) for t, _, r in p.samples], RSS_AFTER_S)
            self.say(f'{p.name:10s}  {(c1 - c0) / max(t1 - t0, 1e-9):7.3f}   {r0 / 2**20:7.1f} MB '
                     f'{base / 2**20:7.1f} MB {r1 / 2**20:7.1f} MB  {growth / 2**20:+7.2f} MB')
            if walked >= 3 * 60 and p.popen is not None:    # the monitor keeps every record: it grows by design
                checks.append(sc.Check(f'RSS growth {p.name}', growth <= self.args.rss_limit_mb * 2**20,
                                       f'{growth / 2**20:+.2f} MB after the first minute (limit '
                                       f'{self.args.rss_limit_mb:g} MB)'))
        self.say('(RSS growth is checked for the robot\'s processes on runs of 3 minutes or more; the soak '
                 'monitor keeps every diagnostics status and read in memory for the report, so it grows)')
        return checks

    def _period_checks(self, walked: float) -> list[sc.Check]:
        """The control period per window with the load beside it; its drift checked on long runs."""
        checks: list[sc.Check] = []
        ts, ps = sc.control_periods(self.reads)
        wins = sc.windows(ts, ps, self.t_walk0, self.window_s)
        self.say(f'control period per {self.window_s:g} s window (t_con between reads of a leg in a swing-down):')
        cores = os.cpu_count() or 1

        def whole(w0: float) -> bool:
            return w0 + self.window_s <= walked + 1e-6
        for w0, n, med, p99 in wins:
            la = [v for t, v in self.load if w0 <= t < w0 + self.window_s]
            part = '' if whole(w0) else f'  (a partial window: {walked - w0:.1f} s, not judged)'
            self.say(f'  {w0 / 60:6.1f} min  n={n:6d}  median {med * 1e3:7.2f} ms  p99 {p99 * 1e3:7.2f} ms  '
                     f'load average {np.mean(la) if la else math.nan:5.1f} on {cores} cores{part}')
        full = [w for w in wins if whole(w[0])]
        if len(full) >= 2:
            d = sc.drift(full[0], full[-1], self.args.period_tolerance)
            if walked >= DRIFT_MIN_S:
                checks.append(d)
            else:
                self.say(f'last window vs first: {d.detail} (a figure: checked on runs of '
                         f'{DRIFT_MIN_S / 60:g} minutes or more)')
        else:
            self.say('(drift needs two full windows)')
        reads = sum(r for _, r, _ in self.timing)
        failed = sum(f for _, _, f in self.timing)
        self.say(f'reads: {reads / walked:.0f} per second, {failed} failed attempts')
        return checks

    def _fault_checks(self) -> list[sc.Check]:
        """Whether every injected fault was reported on /diagnostics and recovered from."""
        checks: list[sc.Check] = []
        faults = self._fault_lines()
        from hexapod_driver.emulator.fault_schedule import CORRUPTED, UNANSWERED, load_replies
        replies = load_replies(self.out / 'replies.bin')

        def times(tick):
            rows = replies[replies[:, 2] == tick]
            return {int(i): rows[rows[:, 1] == i, 0] for i in np.unique(rows[:, 1])}

        verdicts = sc.judge_faults(faults, [s for s in self.statuses if 'hexapod_driver' in s['name']],
                                   self.all_ids, self.t_walk1, FAULT_POLICY, times(UNANSWERED), times(CORRUPTED))
        unobservable = [v for v in verdicts if v.seen is None]
        verdicts = [v for v in verdicts if v.seen is not None]
        seen = sum(bool(v.seen) for v in verdicts)
        due = [v for v in verdicts if v.recovered is not None]
        rec = sum(bool(v.recovered) for v in due)
        self.say(f'faults: {len(verdicts) + len(unobservable)} injected, {seen} reported on /diagnostics, {rec} of '
                 f'{len(due)} recovered (policy {FAULT_POLICY})')
        for v in unobservable:
            why = ('the driver sent that servo no request while it was silent (a swing-down reads only the swinging '
                   'femurs)' if v.text.startswith('silent') else 'no request of its seconds drew the fault')
            self.say(f'  fault {v.fault} at {v.start - self.t_walk0:.1f} s: {v.text}: not observable, {why}')
        for v in verdicts:
            if not v.seen or v.recovered is False:
                self.say(f'  fault {v.fault} at {v.start - self.t_walk0:.1f} s: {v.text}: '
                         f'{"seen" if v.seen else "NOT REPORTED"}, '
                         f'{"recovered" if v.recovered else "NOT RECOVERED"}')
        checks.append(sc.Check('faults reported', seen == len(verdicts) and len(verdicts) > 0,
                               f'{seen} of {len(verdicts)}'))
        checks.append(sc.Check('faults recovered', rec == len(due), f'{rec} of {len(due)}'))
        return checks

    def _end_checks(self) -> list[sc.Check]:
        """Torque off at the end, one /joint_states publisher, the robot's exit code."""
        checks: list[sc.Check] = []
        final = self._final_registers()
        if final is None:
            checks.append(sc.Check('torque off at the end', False, 'the emulator wrote no final registers'))
        else:
            on = [s['id'] for s in final if s['torque_enable']]
            checks.append(sc.Check('torque off at the end', not on,
                                   f'torque enable 1 on ids {on}' if on else f'0 on all {len(final)} servos'))
        checks.append(sc.Check('one /joint_states publisher', self.js_publishers == 1,
                               f'at most {self.js_publishers} publisher(s) seen on ROS_DOMAIN_ID='
                               f'{os.environ.get("ROS_DOMAIN_ID", "0")} (the robot\'s alone: give the soak a domain of '
                               f'its own)'))
        robot_rc = self.procs['robot'].popen.returncode
        checks.append(sc.Check('robot exit code', robot_rc == 0, str(robot_rc)))
        return checks

    def _bag_checks(self) -> list[sc.Check]:
        from hexapod_driver.emulator.fault_schedule import load_replies
        from hexapod_model.servo import servo_tick
        bag = self.out / 'bag'
        size = sum(f.stat().st_size for f in bag.rglob('*') if f.is_file()) if bag.exists() else 0
        try:
            from rosbags.highlevel import AnyReader
            from rosbags.highlevel.anyreader import AnyReaderError
        except ImportError as exc:
            return [sc.Check('bag readable', False, f'rosbags is not installed: {exc}')]
        counts: dict[str, int] = {}
        published: dict[int, list[int]] = {}
        mounts = {bj.joint: bj for bj in self.robot.bus.joints}
        last = -math.inf
        try:
            with AnyReader([bag]) as reader:
                promised = {c.topic: 0 for c in reader.connections}
                for c in reader.connections:
                    promised[c.topic] += c.msgcount
                for conn, t_ns, raw in reader.messages():
                    counts[conn.topic] = counts.get(conn.topic, 0) + 1
                    last = max(last, t_ns * 1e-9)
                    if conn.topic.lstrip('/') == 'joint_states':
                        msg = reader.deserialize(raw, conn.msgtype)
                        for name, theta in zip(msg.name, msg.position):
                            tick = int(round(float(servo_tick(theta, self.robot.servo, mounts[name]))))
                            published.setdefault(mounts[name].servo_id, []).append(tick)
        except (AnyReaderError, OSError, KeyError, ValueError) as exc:
            return [sc.Check('bag readable', False, f'rosbags: {type(exc).__name__}: {exc}')]
        self.say(f'bag: {bag} {size / 2**20:.1f} MB; ' + ', '.join(f'{k} {v}' for k, v in sorted(counts.items())))
        out = [sc.Check('bag readable', counts == promised and bool(counts),
                        f'rosbags read {sum(counts.values())} messages, metadata promises {sum(promised.values())}'),
               sc.Check('bag up to the end', last >= self.t_walk1 - 2.0,
                        f'last message {self.t_walk1 - last:+.1f} s before the end of walking')]
        replies = load_replies(self.out / 'replies.bin')
        replies = replies[replies[:, 2] >= 0]              # positions, not the rows of requests without one
        reported = {int(i): replies[replies[:, 1] == i, 2] for i in np.unique(replies[:, 1])}
        bad, examples = sc.invented_positions({k: np.asarray(v) for k, v in published.items()}, reported)
        n = sum(len(v) for v in published.values())
        out.append(sc.Check('no invented positions', bad == 0 and n > 0,
                            f'{n} published positions, {bad} not reported by the servo' +
                            (': ' + '; '.join(examples) if examples else '')))
        return out


class ChildExited(RuntimeError):
    pass


def parse_args(argv):
    from hexapod_model import cli_common as cc
    ap = cc.make_parser('soak', __doc__.split('\n\n')[0])
    ap.add_argument('--minutes', type=cc.positive_float, required=True, help='minutes of walking')
    ap.add_argument('--seed', type=int, default=0, help='seed of the fault schedule and the /cmd_vel sequence')
    ap.add_argument('--out', type=cc.new_directory, default=None,
                    help='output directory to create (bag, logs, report); default soak-DATE-TIME here')
    ap.add_argument('--rss-limit-mb', type=cc.positive_float, default=10.0,
                    help='allowed RSS growth after the first minute, per process [MB]')
    ap.add_argument('--period-tolerance', type=cc.positive_float, default=0.10,
                    help='allowed change of the control period median and p99, last window against the first '
                         '(a fraction)')
    args = ap.parse_args(argv)
    if args.period_tolerance >= 1:
        cc.fail(ap, f'--period-tolerance must be a fraction below 1, got {args.period_tolerance:g}')
    return args, Path(args.out or time.strftime('soak-%Y%m%d-%H%M%S'))


def main(argv=None) -> int:
    args, out = parse_args(sys.argv[1:] if argv is None else argv)
    try:
        out.mkdir(parents=True)
    except OSError as exc:
        print(f'soak: cannot create {out}: {exc}', file=sys.stderr)
        return EXIT_USAGE
    soak = Soak(args, out)
    try:
        soak.run()
    except KeyboardInterrupt:         # Ctrl-C before run() took SIGINT over (while it imports rclpy)
        soak.interrupted = True
    checks = soak.report()
    failed = [c for c in checks if not c.ok]
    soak.say(f'soak: {"all checks passed" if not failed else f"{len(failed)} check(s) failed"}; report in '
             f'{out / "report.txt"}')
    return EXIT_CHECK_FAILED if failed else EXIT_OK


if __name__ == '__main__':
    sys.exit(main())
