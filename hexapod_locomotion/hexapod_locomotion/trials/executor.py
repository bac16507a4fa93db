"""Run independent jobs (simulated trials, benchmark cases) in order-preserving parallel maps. No rclpy.

Three executors behind one call, :func:`map_jobs`:

* in this process (``jobs`` 1), one after the other;
* a local process pool (``jobs`` > 1, ``concurrent.futures.ProcessPoolExecutor``);
* Ray tasks (``ray_address`` given): ``'local'`` starts a Ray instance on this machine for the run
  (``num_cpus = jobs``, no dashboard) and stops it afterwards; any other value is the address of
  a running cluster (``ray start --head`` on one machine, ``ray start --address HEAD:6379`` on the
  others; ``auto`` finds the cluster this machine belongs to), whose CPUs then set the parallelism.

A job is a picklable module-level function and one argument; results come back in the order of the
arguments whatever the executor, so the same inputs give the same outputs (the jobs themselves are
deterministic for their seeds). A failing job raises in the caller with the job's own exception.
Progress: a tqdm bar on stderr.

Ctrl-C (``KeyboardInterrupt`` in the caller) cancels the queued jobs, stops the running ones (the
pool's worker processes are terminated, Ray tasks cancelled) and raises :class:`JobsInterrupted`
with the results of the jobs that had finished. Pool workers ignore SIGINT themselves, so a Ctrl-C
sent to the terminal's whole process group does not print a traceback per worker.
"""
from __future__ import annotations

import os
import sys
from concurrent.futures import ProcessPoolExecutor, as_completed
from typing import Callable, Iterable, TypeVar

T = TypeVar('T')
R = TypeVar('R')

LOCAL_RAY = 'local'          # --ray without an address


class ExecutorError(RuntimeError):
    """The executor could not be used (the message names why: Ray missing, cluster unreachable)."""


class JobsInterrupted(KeyboardInterrupt):
    """Ctrl-C during :func:`map_jobs`: the unfinished jobs were cancelled. ``results`` is in the order
    of the arguments with ``None`` for a job that did not finish; ``finished`` counts the others."""

    def __init__(self, results: list, done: list[bool]):
        super().__init__(f'interrupted after {sum(done)} of {len(done)} jobs')
        self.results = results
        self.done = done
        self.finished = sum(done)

    def finished_results(self) -> list:
        """The finished jobs' results, in argument order."""
        return [r for r, d in zip(self.results, self.done) if d]


def _ignore_sigint() -> None:
    """Pool worker initializer: Ctrl-C is the caller's to handle (it terminates the workers)."""
    import signal
    signal.signal(signal.SIGINT, signal.SIG_IGN)


def add_executor_options(ap, what: str = 'trials') -> None:
    """``--jobs N`` and ``--ray [ADDRESS]`` on an argparse parser."""
    from hexapod_model.cli_common import positive_int
    ap.add_argument('--jobs', type=positive_int, default=max(1, os.cpu_count() or 1),
                    help=f'parallel {what} (processes; with --ray and no address: CPUs of the local Ray instance)')
    ap.add_argument('--ray', nargs='?', const=LOCAL_RAY, default=None, metavar='ADDRESS',
                    help=f'run the {what} as Ray tasks: without ADDRESS on a Ray instance started here for '
                         'this run; with ADDRESS (host:port, or auto) on that running cluster (docs/performance.md)')


def map_jobs(fn: Callable[[T], R], args: Iterable[T], jobs: int = 1, ray_address: str | None = None,
             desc: str = 'jobs', unit: str = 'job', progress: bool = True) -> list[R]:
    """``[fn(a) for a in args]`` on the chosen executor, results in the order of ``args``."""
    from tqdm import tqdm
    items = list(args)
    out: list = [None] * len(items)
    bar = dict(total=len(items), desc=desc, unit=unit, file=sys.stderr, disable=not progress)
    if ray_address is not None:
        return _map_ray(fn, items, jobs, ray_address, bar)
    done = [False] * len(items)
    if jobs <= 1 or len(items) <= 1:
        try:
            for i, a in enumerate(tqdm(items, **bar)):
                out[i] = fn(a)
                done[i] = True
        except KeyboardInterrupt:
            raise JobsInterrupted(out, done) from None
        return out
    ex = ProcessPoolExecutor(max_workers=min(jobs, len(items)), initializer=_ignore_sigint)
    try:
        futs = {ex.submit(fn, a): i for i, a in enumerate(items)}
        for f in tqdm(as_completed(futs), **bar):
            out[futs[f]] = f.result()
            done[futs[f]] = True
    except KeyboardInterrupt:
        _stop_pool(ex)
        raise JobsInterrupted(out, done) from None
    except BaseException:
        _stop_pool(ex)
        raise
    ex.shutdown(wait=True)
    return out


def _stop_pool(ex: ProcessPoolExecutor, timeout_s: float = 5.0) -> None:
    """Cancel the queued jobs and terminate the workers now (``shutdown`` alone waits for the running
    jobs, and without ``cancel_futures`` for the queued ones too)."""
    workers = list((getattr(ex, '_processes', None) or {}).values())
    ex.shutdown(wait=False, cancel_futures=True)
    for p in workers:
        if p.is_alive():
            p.terminate()
    for p in workers:
        p.join(timeout_s)


def _map_ray(fn, items: list, jobs: int, address: str, bar: dict) -> list:
    from tqdm import tqdm
    try:
        import ray
    except ImportError:
        raise ExecutorError('--ray needs the ray package (pinned in requirements/py.txt; run ./hexapod setup)') from None
    started = False
    if not ray.is_initialized():
        # Workers import the workspace's packages from their own environment: a local instance
        # inherits this process's; on a cluster every node runs `./hexapod shell ray start ...` from
        # a checkout of the same commit (docs/performance.md).
        kwargs = dict(include_dashboard=False, log_to_driver=False, logging_level='ERROR')
        if address not in (LOCAL_RAY, 'auto') and not address.startswith('ray://'):
            _check_reachable(address)
        try:
            if address == LOCAL_RAY:
                ray.init(num_cpus=jobs, **kwargs)
            else:
                ray.init(address=address, **kwargs)
        except Exception as exc:   # noqa: BLE001 - ray raises ConnectionError, ValueError, RuntimeError...
            first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
            raise ExecutorError(f'could not start or reach Ray at {address!r}: {first}') from None
        started = True
    try:
        task = ray.remote(num_cpus=1, max_retries=0)(fn)
        refs = [task.remote(a) for a in items]
        index = {r: i for i, r in enumerate(refs)}
        out: list = [None] * len(items)
        finished = [False] * len(items)
        pending = list(refs)
        try:
            with tqdm(**bar) as progress:
                while pending:
                    ready, pending = ray.wait(pending, num_returns=1)
                    for r in ready:
                        try:
                            out[index[r]] = ray.get(r)
                        except ray.exceptions.RayTaskError as exc:
                            raise exc.as_instanceof_cause() from None
                        finished[index[r]] = True
                        progress.update(1)
        except KeyboardInterrupt:
            for r in pending:
                try:
                    ray.cancel(r, force=True)
                except Exception:   # noqa: BLE001 - a task that finished meanwhile cannot be cancelled
                    pass
            raise JobsInterrupted(out, finished) from None
        return out
    finally:
        if started:
            ray.shutdown()


def _check_reachable(address: str, timeout_s: float = 5.0) -> None:
    """Refuse an address whose GCS port does not answer (Ray itself would retry for minutes)."""
    import socket
    host, sep, port = address.rpartition(':')
    if not sep or not port.isdigit() or not host:
        raise ExecutorError(f'Ray address must be HOST:PORT (e.g. 10.0.0.5:6379), auto, or nothing; got {address!r}')
    try:
        socket.create_connection((host, int(port)), timeout=timeout_s).close()
    except OSError as exc:
        raise ExecutorError(f'no Ray cluster answers at {address} ({exc.strerror or exc}); start one with '
                            f'`ray start --head` there, or drop the address for a local instance') from None
