"""A seeded fuzzer over bags and robot descriptions: do the tools fail in one line, or read what they can?

    ./hexapod run hexapod_locomotion fuzz_inputs [--cases 1000] [--seed 0] [--out DIR] [--only I ...]
    ./hexapod run hexapod_locomotion fuzz_inputs --lost-chunk BAG [--at F ...] [--seconds S] [--chunk-kb K]

Each case damages a small valid input and runs the tools on it in this process:

- bags (from the first seconds of ``bags/tripod_blocks_adaptive``): bit flips, truncation at a chunk
  boundary (and a few bytes either side), a huge record length field, a topic recorded with the wrong
  message type, a ``metadata.yaml`` that lies (counts, files, version, storage, types, garbage);
  run through ``analyse``, ``discrepancy`` and the reader ``replay`` plays from (:class:`BagReader`
  and its messages);
- robot descriptions and overlays (from ``robot.yaml``): a value of the wrong type, NaN, infinite,
  negative, a missing key; run through ``load_robot`` (what every tool and node loads) and
  ``discrepancy --robot``/``--overlay``.

A case passes if each tool ends with code 0 (at most one warning line) or 2 (exactly one error line),
prints no traceback, and uses at most 10 s of CPU time (:data:`CASE_LIMIT_S`; a tool still working at
three times that is stopped). The wall time is not judged by that budget: on a loaded machine a tool
that works waits for a core, and its wall time grows while its CPU time does not. A tool that has not
ended after :data:`HANG_LIMIT_S` of wall time is stopped and fails as hung (a process blocked, using no
CPU, never reaches its CPU budget). A failing case prints its seed and what happened; a progress line
every 10 cases; at the end, cases and failures per kind of damage, per tool its runs, how they ended,
the runs over the CPU budget, the hung ones and the passing ones that took more than 10 s of wall time,
its slowest run, and the peak memory of the run (every case under 1 GB if the run's peak is). The exit
code is 1 if any case failed.

``--lost-chunk BAG`` breaks one chunk of a copy of BAG at a time and prints what ``discrepancy`` makes of
each: the spans lost, walk or stand with the effects it names, or its one-line refusal.
"""
from __future__ import annotations

import argparse
import contextlib
import io
import math
import random
import resource
import shutil
import signal
import struct
import sys
import tempfile
import time
import traceback
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import yaml

from hexapod_sim.bagio import BagError, BagReader, BagWarning, BagWriter

CASE_LIMIT_S = 10.0         # CPU time a tool run may use [s]
CPU_STOP_FACTOR = 3.0       # a run still working at this many times CASE_LIMIT_S of CPU time is stopped
HANG_LIMIT_S = 120.0        # wall time after which a run that has not ended is stopped as hung [s]
BASE_SECONDS = 2.5          # of the reference walk in the base bag
BAG_KINDS = ('bitflip', 'truncate', 'huge_length', 'wrong_type', 'metadata_lies')
DESC_KINDS = ('wrong_type', 'nan', 'inf', 'negative', 'missing_key')


def reference_bag() -> Path:
    from hexapod_sim.bagio.recorder import default_bag_root
    return default_bag_root() / 'tripod_blocks_adaptive'


def make_base_bag(dst: Path, seconds: float = BASE_SECONDS) -> Path:
    """The first ``seconds`` of the reference walk as a small complete bag."""
    return copy_bag(reference_bag(), dst, seconds, 64)


def warm_up(base: Path) -> list[Outcome]:
    """The bag tools run once on the undamaged ``base``, unjudged: the first run in a process compiles
    the leg model's numba kernels (cached on disk after), which is no tool's work on a damaged input (a
    first case on a fresh build used 30 s of CPU time for a tool that then needs 2.5 s)."""
    return bag_tools(base)


def copy_bag(src: Path, dst: Path, seconds: float | None, chunk_kb: int) -> Path:
    """The first ``seconds`` (None: all) of the bag ``src`` written to ``dst`` in chunks of ``chunk_kb`` KiB."""
    with warnings.catch_warnings():
        warnings.simplefilter('ignore', BagWarning)
        r = BagReader(src)
    end = None if seconds is None else r.start_ns + int(seconds * 1e9)
    with BagWriter(dst, chunk_size=chunk_kb * 1024) as w:
        for topic, info in r.topic_info().items():
            w.add_topic(topic, info.msg_type, definition=r.schema_text(topic),
                        qos_profiles=list(info.offered_qos_profiles) or None)
        for topic, msg_type, t_ns, data in r.messages(raw=True, end_ns=end):
            w.write(topic, msg_type, data, t_ns)
    return dst


def break_chunk(bag: Path, dst: Path, k: int) -> Path:
    """A copy of ``bag`` at ``dst`` whose ``k``-th chunk fails its CRC (the reader skips it)."""
    shutil.copytree(bag, dst)
    mcap = next(dst.glob('*.mcap'))
    data = bytearray(mcap.read_bytes())
    off, _, length = [r for r in _records(bytes(data)) if r[1] == 0x06][k]
    data[off + 9 + length - 50] ^= 0xFF
    mcap.write_bytes(bytes(data))
    return dst


def lost_chunk_runs(src: Path, work: Path, seconds: float | None, chunk_kb: int, chunks: list[float]) -> list[str]:
    """What ``discrepancy`` makes of ``src`` (its first ``seconds``, in ``chunk_kb`` KiB chunks) with one chunk
    broken, for each chunk at the given fractions of the chunk count: the spans lost, and walk or stand
    with the effects named, or its refusal."""
    from hexapod_sim.discrepancy import RecordingError, analyse, load_recording
    base = copy_bag(src, work / 'whole', seconds, chunk_kb)
    n = len([r for r in _records(next(base.glob('*.mcap')).read_bytes()) if r[1] == 0x06])
    out = []
    for k in sorted({min(max(int(f * n), 1), n - 2) for f in chunks}):
        with warnings.catch_warnings():
            warnings.simplefilter('ignore')
            rec = load_recording(break_chunk(base, work / f'chunk_{k}', k))
            lost = ', '.join(f'{a:.2f}-{b:.2f} s' for a, b in rec.lost)
            try:
                res = analyse(rec)
            except RecordingError as exc:
                out.append(f'chunk {k} of {n} (lost {lost}): refused: {str(exc).split(": ")[-1]}')
                continue
        named = '; '.join(f'{f.effect.effect} on {f.scope}: ' + ', '.join(f'{p}={v:.3g}' for p, v in f.effect.params.items())
                          for f in res.effects)
        out.append(f'chunk {k} of {n} (lost {lost}): {res.mode}, {named or "no effect named"}')
    return out


def _records(data: bytes) -> list[tuple[int, int, int]]:
    """(offset, opcode, length) of each top-level MCAP record."""
    out, pos = [], 8
    while pos + 9 <= len(data):
        op, length = struct.unpack_from('<BQ', data, pos)
        out.append((pos, op, length))
        if pos + 9 + length > len(data):
            break
        pos += 9 + length
    return out


def mutate_bag(base: Path, dst: Path, kind: str, rng: random.Random) -> str:
    """Copy ``base`` to ``dst`` damaged as ``kind``; a short description of the damage."""
    shutil.copytree(base, dst)
    mcap = next(dst.glob('*.mcap'))
    data = bytearray(mcap.read_bytes())
    meta_path = dst / 'metadata.yaml'
    if kind == 'bitflip':
        n = rng.choice((1, 4, 32))
        for _ in range(n):
            i = rng.randrange(len(data))
            data[i] ^= 1 << rng.randrange(8)
        mcap.write_bytes(bytes(data))
        return f'{n} bit flip(s)'
    if kind == 'truncate':
        recs = _records(bytes(data))
        chunks = [off for off, op, _ in recs if op == 0x06] + [len(data)]
        cut = max(0, min(len(data), rng.choice(chunks) + rng.choice((0, 0, 1, -1, 9, -9, 100))))
        mcap.write_bytes(bytes(data[:cut]))
        return f'truncated at byte {cut} of {len(data)}'
    if kind == 'huge_length':
        off, op, _ = rng.choice(_records(bytes(data)))
        huge = rng.choice((2**63 - 1, 2**64 - 1, 2**40, len(data) * 4))
        struct.pack_into('<Q', data, off + 1, huge)
        mcap.write_bytes(bytes(data))
        return f'length of the record (opcode 0x{op:02x}) at byte {off} set to {huge}'
    if kind == 'wrong_type':
        with warnings.catch_warnings():
            warnings.simplefilter('ignore', BagWarning)
            r = BagReader(base)
        topic = rng.choice(sorted(r.topics()))
        other = rng.choice(sorted({t for t in r.topics().values()} - {r.topics()[topic]}))
        shutil.rmtree(dst)
        with BagWriter(dst) as w:        # the topic's messages as they are, its schema another type's
            for t, info in r.topic_info().items():
                typ = other if t == topic else info.msg_type
                w.add_topic(t, typ, definition=None if t == topic else r.schema_text(t))
            for t, msg_type, t_ns, raw in r.messages(raw=True):
                w.write(t, other if t == topic else msg_type, raw, t_ns)
        return f'{topic} recorded as {other}'
    meta = yaml.safe_load(meta_path.read_text())
    info = meta['rosbag2_bagfile_information']
    lie = rng.choice(('counts', 'missing_file', 'extra_file', 'version', 'storage', 'topic_type', 'garbage',
                      'not_a_dict', 'no_topics', 'negative_duration', 'empty'))
    if lie == 'counts':
        for e in info['topics_with_message_count']:
            e['message_count'] = rng.choice((0, 10**12, -5))
        info['message_count'] = 10**15
    elif lie == 'missing_file':
        info['relative_file_paths'] = ['elsewhere_0.mcap']
    elif lie == 'extra_file':
        info['relative_file_paths'] = info['relative_file_paths'] + ['../../etc/passwd', 'metadata.yaml']
    elif lie == 'version':
        info['version'] = rng.choice((99, 'nine', None))
    elif lie == 'storage':
        info['storage_identifier'] = rng.choice(('sqlite3', 42, None))
    elif lie == 'topic_type':
        for e in info['topics_with_message_count']:
            e['topic_metadata']['type'] = rng.choice(('std_msgs/msg/String', 'no/such/Type', 7, None))
    elif lie == 'negative_duration':
        info['duration'] = {'nanoseconds': -10**18}
        info['starting_time'] = {'nanoseconds_since_epoch': 'yesterday'}
    elif lie == 'no_topics':
        info['topics_with_message_count'] = 'none'
    if lie == 'garbage':
        meta_path.write_bytes(bytes(rng.randrange(256) for _ in range(200)))
    elif lie == 'not_a_dict':
        meta_path.write_text(rng.choice(('[1, 2, 3]\n', 'just text\n', 'rosbag2_bagfile_information: 5\n')))
    elif lie == 'empty':
        meta_path.write_text('')
    else:
        meta_path.write_text(yaml.safe_dump(meta))
    return f'metadata.yaml lies: {lie}'


def _leaves(obj, path=()):
    if isinstance(obj, dict):
        for k, v in obj.items():
            yield from _leaves(v, path + (k,))
    elif isinstance(obj, list) and obj and not all(isinstance(x, (int, float)) for x in obj):
        for i, v in enumerate(obj):
            yield from _leaves(v, path + (i,))
    else:
        yield path, obj


def mutate_description(dst: Path, kind: str, rng: random.Random) -> tuple[str, bool]:
    """A damaged robot description written to ``dst``; (what was done, used as an overlay?)."""
    from hexapod_model.description import default_description_path
    doc = yaml.safe_load(default_description_path().read_text())
    path, value = rng.choice(list(_leaves(doc)))
    parent = doc
    for k in path[:-1]:
        parent = parent[k]
    key = path[-1]
    if kind == 'wrong_type':
        new = rng.choice(('text', [1, 2], {'a': 1}, True, None))
    elif kind == 'nan':
        new = math.nan
    elif kind == 'inf':
        new = rng.choice((math.inf, -math.inf))
    elif kind == 'negative':
        new = -abs(value) - 1.0 if isinstance(value, (int, float)) and not isinstance(value, bool) else -1.0
    else:
        new = None
    if kind == 'missing_key':
        del parent[key]
    else:
        parent[key] = new
    as_overlay = rng.random() < 0.5
    out = doc
    if as_overlay:                   # only the damaged branch, as an overlay file holds it
        out = {}
        node = out
        src = doc
        for k in path[:-1]:
            src = src[k]
            if isinstance(k, int):   # a list element: the overlay carries the whole list
                break
            node = node.setdefault(k, {} if isinstance(src, dict) else src)
        if isinstance(node, dict) and kind != 'missing_key' and not isinstance(key, int):
            node[key] = new
    dst.write_text(yaml.safe_dump(out, allow_unicode=True))
    return f'{"/".join(map(str, path))}: {kind}{"" if kind == "missing_key" else f" -> {new!r}"}' + \
        (' (overlay)' if as_overlay else ''), as_overlay


@dataclass
class Outcome:
    tool: str
    code: int | None
    lines: list
    seconds: float                  # wall time
    trace: str = ''
    cpu_s: float = float('nan')     # CPU time of this process (every thread) meanwhile, what CASE_LIMIT_S
                                    # judges: a loaded machine stretches the wall time, a tool that works
                                    # longer the CPU time
    stopped: str = ''               # 'cpu': stopped over the CPU budget; 'hang': over HANG_LIMIT_S of wall time

    def limit(self, budget: bool = True) -> str:
        """Which time limit the run failed: 'hang', 'cpu' or ''. ``budget=False`` judges only the stops
        (a runaway at CPU_STOP_FACTOR x CASE_LIMIT_S, a hang), not a run that ended a little over its
        CPU budget: the speed figure this command prints, which the tests leave to it (a CPU time moves
        with the machine's load too, through cache and memory contention)."""
        if self.stopped == 'hang':
            return 'hang'
        return 'cpu' if self.stopped == 'cpu' or (budget and self.cpu_s > CASE_LIMIT_S) else ''

    def problem(self, budget: bool = True) -> str:
        """What is wrong with the run ('' if nothing); ``budget`` as for :meth:`limit`."""
        if self.trace:
            return f'{self.tool}: uncaught {self.trace}'
        if self.limit(budget) == 'hang':
            return f'{self.tool}: hung: no end after {self.seconds:.1f} s wall (CPU {self.cpu_s:.1f} s)'
        if self.limit(budget) == 'cpu':
            return (f'{self.tool}: over the CPU budget: {self.cpu_s:.1f} s of CPU time (limit {CASE_LIMIT_S:g} s)'
                    f'{", stopped" if self.stopped else ""}, {self.seconds:.1f} s wall')
        if self.code == 2 and len(self.lines) != 1:
            return f'{self.tool}: exit 2 with {len(self.lines)} stderr lines: {self.lines[:3]}'
        if self.code == 0 and len([x for x in self.lines if 'warning' in x]) > 1:
            return f'{self.tool}: {len(self.lines)} warning lines: {self.lines[:3]}'
        if self.code not in (0, 2):
            return f'{self.tool}: exit {self.code}: {self.lines[-1:]}'
        return ''


class _Stopped(BaseException):     # not an Exception: a tool's own ``except Exception`` lets it through
    """Raised in the tool by a timer: ``args[0]`` is 'cpu' (its CPU budget) or 'hang' (HANG_LIMIT_S)."""


def _stop_cpu(signum, frame):
    raise _Stopped('cpu')


def _stop_hang(signum, frame):
    raise _Stopped('hang')


def run_tool(name: str, fn) -> Outcome:
    """``fn()`` (a tool's main, returning its exit code) with stderr captured, stopped at
    CPU_STOP_FACTOR x CASE_LIMIT_S of CPU time (``ITIMER_PROF``: this process's user and system time)
    or at HANG_LIMIT_S of wall time (``ITIMER_REAL``), whichever comes first."""
    err = io.StringIO()
    t0, cpu0 = time.perf_counter(), time.process_time()
    code, trace, stopped = None, '', ''
    old = signal.signal(signal.SIGALRM, _stop_hang), signal.signal(signal.SIGPROF, _stop_cpu)
    signal.setitimer(signal.ITIMER_REAL, HANG_LIMIT_S)
    signal.setitimer(signal.ITIMER_PROF, CASE_LIMIT_S * CPU_STOP_FACTOR)
    try:
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()), warnings.catch_warnings():
            warnings.simplefilter('ignore')
            code = fn()
    except SystemExit as exc:
        code = exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 1)
    except _Stopped as exc:
        stopped = exc.args[0]
    except BaseException as exc:           # noqa: BLE001 - what the fuzzer looks for
        tb = traceback.extract_tb(exc.__traceback__)[-1]
        trace = f'{type(exc).__name__}: {str(exc)[:200]} ({Path(tb.filename).name}:{tb.lineno})'
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.setitimer(signal.ITIMER_PROF, 0)
        signal.signal(signal.SIGALRM, old[0])
        signal.signal(signal.SIGPROF, old[1])
    lines = [x for x in err.getvalue().splitlines() if x.strip()]
    if 'Traceback' in err.getvalue():
        trace = trace or 'traceback printed: ' + lines[-1][:200]
    return Outcome(name, code, lines, time.perf_counter() - t0, trace, time.process_time() - cpu0, stopped)


def _read_all(bag: Path) -> int:
    """What ``replay`` does with a bag before publishing: open it, decode every message."""
    try:
        r = BagReader(bag)
    except BagError as exc:
        print(f'replay: error: {exc}', file=sys.stderr)
        return 2
    for w in r.warnings[:1]:
        print(f'replay: warning: {w}', file=sys.stderr)
    for _ in r.messages():
        pass
    return 0


def bag_tools(bag: Path) -> list[Outcome]:
    from hexapod_locomotion.trials.analyse import main as analyse
    from hexapod_sim.discrepancy.cli import main as discrepancy
    return [run_tool('analyse', lambda: analyse([str(bag), '--no-progress'])),
            run_tool('discrepancy', lambda: discrepancy([str(bag), '--no-progress'])),
            run_tool('replay-reader', lambda: _read_all(bag))]


def description_tools(desc: Path, as_overlay: bool, bag: Path) -> list[Outcome]:
    from hexapod_model.description import DescriptionError, load_robot
    from hexapod_sim.discrepancy.cli import main as discrepancy

    def load() -> int:
        try:
            load_robot(None if as_overlay else desc, overlays=[desc] if as_overlay else ())
        except DescriptionError as exc:
            print(f'load_robot: error: {exc}', file=sys.stderr)
            return 2
        return 0
    flag = ['--overlay', str(desc)] if as_overlay else ['--robot', str(desc)]
    return [run_tool('load_robot', load),
            run_tool('discrepancy', lambda: discrepancy([str(bag), '--no-progress', *flag]))]


def run_case(i: int, seed: int, base: Path, work: Path) -> tuple[str, str, list[Outcome]]:
    """(kind of damage, what was done, each tool's outcome) of case ``i``."""
    rng = random.Random(f'{seed}:{i}')
    case_dir = work / f'case_{i}'
    case_dir.mkdir()
    try:
        if rng.random() < 0.7:
            kind = rng.choice(BAG_KINDS)
            what = f'bag {kind}: ' + mutate_bag(base, case_dir / 'bag', kind, rng)
            return f'bag {kind}', what, bag_tools(case_dir / 'bag')
        kind = rng.choice(DESC_KINDS)
        desc = case_dir / 'robot.yaml'
        what, as_overlay = mutate_description(desc, kind, rng)
        return f'description {kind}', 'description ' + what, description_tools(desc, as_overlay, base)
    finally:
        shutil.rmtree(case_dir, ignore_errors=True)


def peak_memory_mb() -> float:
    """The peak resident memory of this process so far (every case runs in it)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


@dataclass
class Tally:
    """The figures of a run: cases and failures per kind of damage (of those, over the CPU budget and
    hung); per tool its runs, how they ended (0 without a warning, 0 with one warning line, 2 with one
    error line), failures (of those, over the CPU budget and hung), passing runs over CASE_LIMIT_S of
    wall time, and its slowest run."""
    kinds: dict = field(default_factory=dict)      # kind -> [cases, failed, over CPU budget, hung]
    tools: dict = field(default_factory=dict)      # tool -> [runs, clean, warned, refused, failed, over CPU
                                                   #          budget, hung, passed over the limit in wall time, slowest s]
    slowest: tuple = (0.0, '', -1, 0.0)            # (seconds, tool, case, CPU seconds)
    most_cpu_s: float = 0.0

    def add(self, i: int, kind: str, outcomes: list[Outcome]) -> list[str]:
        """Count case ``i``; its problems (empty if it passed)."""
        problems = [p for p in (o.problem() for o in outcomes) if p]
        limits = {o.limit() for o in outcomes if not o.trace}
        k = self.kinds.setdefault(kind, [0, 0, 0, 0])
        k[0] += 1
        k[1] += bool(problems)
        k[2] += 'cpu' in limits
        k[3] += 'hang' in limits
        for o in outcomes:
            t = self.tools.setdefault(o.tool, [0, 0, 0, 0, 0, 0, 0, 0, 0.0])
            failed = bool(o.problem())
            t[0] += 1
            t[1] += not failed and o.code == 0 and not any('warning' in x for x in o.lines)
            t[2] += not failed and o.code == 0 and any('warning' in x for x in o.lines)
            t[3] += not failed and o.code == 2
            t[4] += failed
            t[5] += not o.trace and o.limit() == 'cpu'
            t[6] += not o.trace and o.limit() == 'hang'
            t[7] += not failed and o.seconds > CASE_LIMIT_S
            t[8] = max(t[8], o.seconds)
            self.most_cpu_s = max(self.most_cpu_s, o.cpu_s)
            if o.seconds > self.slowest[0]:
                self.slowest = (o.seconds, o.tool, i, o.cpu_s)
        return problems

    @property
    def failed(self) -> int:
        return sum(k[1] for k in self.kinds.values())

    def report(self) -> list[str]:
        out = [f'kind of damage: cases, failed (of those: over the {CASE_LIMIT_S:g} s CPU budget, hung: no end after '
               f'{HANG_LIMIT_S:g} s wall)']
        out += [f'  {k}: {n}, {f} ({c}, {h})' for k, (n, f, c, h) in sorted(self.kinds.items())]
        out.append('tool: runs, exit 0 clean, exit 0 with one warning, exit 2 with one line, failed (over the CPU '
                   f'budget, hung), passed over {CASE_LIMIT_S:g} s wall, slowest s')
        out += [f'  {name}: {t[0]}, {t[1]}, {t[2]}, {t[3]}, {t[4]} ({t[5]}, {t[6]}), {t[7]}, {t[8]:.2f}'
                for name, t in sorted(self.tools.items())]
        s, tool, i, cpu = self.slowest
        out.append(f'slowest tool run: {tool} on case {i}, {s:.2f} s (CPU {cpu:.2f} s); most CPU time of a tool run '
                   f'{self.most_cpu_s:.2f} s')
        return out


def _lost_chunk_main(opts) -> int:
    from hexapod_sim.discrepancy import RecordingError
    if opts.chunk_kb < 1 or not all(0.0 <= f <= 1.0 for f in opts.at):
        print('fuzz_inputs: error: --chunk-kb must be at least 1 and --at fractions within 0-1', file=sys.stderr)
        return 2
    work = Path(tempfile.mkdtemp(prefix='lost_chunk_'))
    try:
        for line in lost_chunk_runs(Path(opts.lost_chunk), work, opts.seconds, opts.chunk_kb, opts.at):
            print(line, flush=True)
    except (BagError, RecordingError) as exc:
        print(f'fuzz_inputs: error: {exc}', file=sys.stderr)
        return 2
    finally:
        shutil.rmtree(work, ignore_errors=True)
    return 0


def main(args=None) -> int:
    ap = argparse.ArgumentParser(prog='fuzz_inputs', description=__doc__.split('\n\n')[0])
    ap.add_argument('--cases', type=int, default=1000)
    ap.add_argument('--seed', type=int, default=0)
    ap.add_argument('--out', default=None, help='work folder (default: a temporary one, removed at the end)')
    ap.add_argument('--lost-chunk', metavar='BAG', help='instead: break one chunk of BAG at a time (at the '
                    '--at fractions of its chunks) and say what discrepancy makes of it')
    ap.add_argument('--at', type=float, nargs='+', default=[0.5], metavar='F', help='with --lost-chunk')
    ap.add_argument('--seconds', type=float, default=None, help='with --lost-chunk: only the first S seconds')
    ap.add_argument('--chunk-kb', type=int, default=64, help='with --lost-chunk: chunk size of the copy [KiB]')
    ap.add_argument('--only', type=int, nargs='+', metavar='I',
                    help='run only these cases (of --seed), each tool\'s ending and time printed')
    opts = ap.parse_args(sys.argv[1:] if args is None else args)
    if opts.lost_chunk:
        return _lost_chunk_main(opts)
    if opts.cases < 1 or any(i < 0 for i in opts.only or ()):
        print('fuzz_inputs: error: --cases must be at least 1 and --only cases not negative', file=sys.stderr)
        return 2
    cases = sorted(set(opts.only)) if opts.only else list(range(opts.cases))
    work = Path(opts.out) if opts.out else Path(tempfile.mkdtemp(prefix='fuzz_inputs_'))
    work.mkdir(parents=True, exist_ok=True)
    base = make_base_bag(work / 'base')
    warm_up(base)
    size_kb = sum(f.stat().st_size for f in base.iterdir()) / 1024
    print(f'fuzz_inputs: {len(cases)} cases (seed {opts.seed}) on a base bag of {size_kb:.0f} kB', flush=True)
    tally, t0 = Tally(), time.monotonic()
    try:
        for n, i in enumerate(cases, 1):
            kind, what, outcomes = run_case(i, opts.seed, base, work)
            problems = tally.add(i, kind, outcomes)
            if problems:
                print(f'case {i} (seed {opts.seed}): {what}: ' + '; '.join(problems), flush=True)
            if opts.only:
                print(f'case {i}: {what}: ' + '; '.join(f'{o.tool} exit {o.code}, {o.seconds:.2f} s (CPU {o.cpu_s:.2f} s)'
                                                        for o in outcomes), flush=True)
            if n % 10 == 0 or n == len(cases):
                print(f'fuzz_inputs: {n}/{len(cases)} cases, {tally.failed} failing, '
                      f'{time.monotonic() - t0:.0f} s, slowest tool run {tally.slowest[0]:.2f} s, '
                      f'peak memory {peak_memory_mb():.0f} MB', file=sys.stderr, flush=True)
    finally:
        if not opts.out:
            shutil.rmtree(work, ignore_errors=True)
    print('\n'.join(tally.report()))
    print(f'fuzz_inputs: {len(cases)} cases (seed {opts.seed}): {len(cases) - tally.failed} passed, '
          f'{tally.failed} failed; slowest tool run {tally.slowest[0]:.2f} s; peak memory of the run '
          f'{peak_memory_mb():.0f} MB; {time.monotonic() - t0:.0f} s')
    return 1 if tally.failed else 0

if __name__ == '__main__':
    sys.exit(main())
