"""What every command-line tool of the workspace shares, so that the commands agree with each other.

* :func:`make_parser`: usage lines name the command the user typed (``./hexapod demo`` when run
  through the ``./hexapod`` script, which exports :data:`PROG_ENV` / :data:`EXE_ENV`), every
  ``--help`` shows the defaults, and a usage error is ONE line on stderr (exit status 2).
* argparse ``type=`` validators with one wording (``must be finite and > 0, got -1``), so bad
  values are refused while the arguments are parsed, before anything is created.
* :data:`OVERLAY_FLAG` / :data:`NO_PROGRESS_FLAG`: one spelling of "read a robot overlay" and of
  "no progress bar" in every tool.

Plain argparse; no ROS.
"""
from __future__ import annotations

import argparse
import math
import os
import sys
import tempfile
from pathlib import Path
from typing import Callable, Iterable

PROG_ENV = 'HEXAPOD_PROG'      # e.g. "./hexapod demo", set by the ./hexapod script
EXE_ENV = 'HEXAPOD_EXE'        # the console script it runs, e.g. "demo"
OVERLAY_FLAG = '--overlay'
NO_PROGRESS_FLAG = '--no-progress'


def prog_name(exe: str) -> str:
    """``./hexapod NAME`` when the ./hexapod script started console script ``exe``, else ``exe``."""
    if os.environ.get(EXE_ENV) == exe and os.environ.get(PROG_ENV):
        return os.environ[PROG_ENV]
    return exe


class HelpFormatter(argparse.RawDescriptionHelpFormatter):
    """Keeps the description's line breaks and appends ``(default: X)`` to every option with a default."""

    def _get_help_string(self, action: argparse.Action) -> str:
        text = action.help or ''
        d = action.default
        if ('default' in text or d is None or d is False or d is argparse.SUPPRESS or d == '' or d == []
                or isinstance(action, (argparse._HelpAction, argparse._VersionAction, argparse._StoreTrueAction,
                                       argparse._StoreFalseAction))):      # a switch has no default to show
            return text
        if action.option_strings or action.nargs in (argparse.OPTIONAL, argparse.ZERO_OR_MORE):
            if isinstance(d, (list, tuple)):
                return f'{text} (default: {" ".join(str(x) for x in d)})'
            return text + ' (default: %(default)s)'
        return text


class ArgumentParser(argparse.ArgumentParser):
    """An argparse parser whose usage errors are one line: ``PROG: error: MESSAGE (see PROG --help)``."""

    def __init__(self, *args, **kw):
        kw.setdefault('formatter_class', HelpFormatter)
        super().__init__(*args, **kw)

    def error(self, message: str):   # noqa: D102 - argparse API
        self.exit(2, f'{self.prog}: error: {message} (see {self.prog} --help)\n')


def make_parser(exe: str, doc: str | None, **kw) -> ArgumentParser:
    """The parser of console script ``exe``; ``doc`` (a module docstring) is its description, printed once."""
    return ArgumentParser(prog=prog_name(exe), description=(doc or '').strip() or None, **kw)


def fail(parser: argparse.ArgumentParser, message: str):
    """Refuse the arguments after parsing (cross-argument checks): one line, exit status 2."""
    parser.error(message)


# ----------------------------------------------------------------------------- value validators
def _float(text: str) -> float:
    try:
        return float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f'expected a number, got {text!r}') from None


def positive_float(text: str) -> float:
    """argparse type: a finite number > 0."""
    v = _float(text)
    if not (math.isfinite(v) and v > 0):
        raise argparse.ArgumentTypeError(f'must be finite and > 0, got {text}')
    return v


def positive_or_inf(text: str) -> float:
    """argparse type: a number > 0, ``inf`` included (no limit)."""
    v = _float(text)
    if not v > 0:
        raise argparse.ArgumentTypeError(f'must be > 0 (inf: no limit), got {text}')
    return v


def positive_float_at_most(limit: float) -> Callable[[str], float]:
    """argparse type: a finite number in (0, limit]."""
    def check(text: str) -> float:
        v = _float(text)
        if not (math.isfinite(v) and 0 < v <= limit):
            raise argparse.ArgumentTypeError(f'must be in (0, {limit:g}], got {text}')
        return v
    return check


def nonnegative_float(text: str) -> float:
    """argparse type: a finite number >= 0."""
    v = _float(text)
    if not (math.isfinite(v) and v >= 0):
        raise argparse.ArgumentTypeError(f'must be finite and >= 0, got {text}')
    return v


def param_float(spec) -> Callable[[str], float]:
    """argparse type for a float parameter of a schema (:class:`hexapod_model.param_schema.ParamSpec`):
    a number its declaration accepts (range and rule), refused with the declaration's own reason."""
    from hexapod_model.param_schema import check

    def parse(text: str) -> float:
        v = _float(text)
        why = check(spec, v)
        if why is not None:
            raise argparse.ArgumentTypeError(why)
        return v
    return parse


def finite_float(text: str) -> float:
    """argparse type: any finite number."""
    v = _float(text)
    if not math.isfinite(v):
        raise argparse.ArgumentTypeError(f'must be finite, got {text}')
    return v


def ratio_at_least_one(text: str) -> float:
    """argparse type: a finite number >= 1 (an improvement factor)."""
    v = _float(text)
    if not (math.isfinite(v) and v >= 1):
        raise argparse.ArgumentTypeError(f'must be finite and >= 1, got {text}')
    return v


def _int(text: str) -> int:
    try:
        return int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f'expected an integer, got {text!r}') from None


def positive_int(text: str) -> int:
    """argparse type: an integer >= 1."""
    v = _int(text)
    if v < 1:
        raise argparse.ArgumentTypeError(f'must be >= 1, got {text}')
    return v


def nonnegative_int(text: str) -> int:
    """argparse type: an integer >= 0."""
    v = _int(text)
    if v < 0:
        raise argparse.ArgumentTypeError(f'must be >= 0, got {text}')
    return v


def port_number(text: str) -> int:
    """argparse type: a TCP port 0..65535 (0: any free port)."""
    v = _int(text)
    if not 0 <= v <= 65535:
        raise argparse.ArgumentTypeError(f'{text}: a port must be 0..65535 (0 = any free port)')
    return v


def existing_file(text: str) -> str:
    """argparse type: a file that exists (e.g. an overlay to read)."""
    if not Path(text).is_file():
        raise argparse.ArgumentTypeError(f'no such file: {text}')
    return text


def existing_path(text: str) -> str:
    """argparse type: a file or directory that exists (e.g. a bag)."""
    if not Path(text).exists():
        raise argparse.ArgumentTypeError(f'no such file or directory: {text}')
    return text


def _cannot_create_in(parent: Path) -> str | None:
    """Why nothing can be created in ``parent`` (None: a probe file could be made, and was removed).
    Tried, not judged by ``os.access``: root passes that on read-only mounts and on /proc."""
    try:
        fd, name = tempfile.mkstemp(dir=parent, prefix='.hexapod_write_probe_')
    except OSError as exc:
        return exc.strerror or str(exc)
    os.close(fd)
    os.unlink(name)
    return None


def new_directory(text: str) -> str:
    """argparse type: a directory to create (e.g. a bag to write): must not exist, its parent must,
    and must take new entries."""
    p = Path(text)
    if p.exists():
        raise argparse.ArgumentTypeError(f'{text}: already exists (choose a new bag directory)')
    parent = p.parent if str(p.parent) else Path('.')
    if not parent.is_dir():
        raise argparse.ArgumentTypeError(f'{text}: directory {parent} does not exist')
    why = _cannot_create_in(parent)
    if why is not None:
        raise argparse.ArgumentTypeError(f'{text}: cannot create it in {parent}: {why}')
    return text


def output_directory(text: str) -> str:
    """argparse type: a folder to write into, created if missing (with its parents): an existing one
    must take new files, else its nearest existing ancestor must take new folders. Parsing leaves
    nothing behind (only a probe file, made and removed: :func:`_cannot_create_in`)."""
    p = Path(text)
    if p.exists() and not p.is_dir():
        raise argparse.ArgumentTypeError(f'{text} is a file, expected a folder')
    base = p
    while not base.exists():
        base = base.parent if str(base.parent) not in ('', str(base)) else Path('.')
    if not base.is_dir():
        raise argparse.ArgumentTypeError(f'{text}: {base} is a file, expected a folder')
    why = _cannot_create_in(base)
    if why is not None:
        raise argparse.ArgumentTypeError(f'{text}: cannot write in {base}: {why}')
    return text


def output_file(extensions: Iterable[str] | Callable[[], Iterable[str]] | None = None, create_parent: bool = False):
    """argparse type: a file to write, in an existing directory, with one of ``extensions``.

    ``extensions`` may be a callable (e.g. matplotlib's registry, imported only when the option is
    given). Checked while parsing, so a run is not lost to a typo in an output name at its end.
    ``create_parent``: the directory may be missing (the tool makes it with :func:`open_for_writing`
    when it writes the file); its nearest existing ancestor must take new folders.
    """
    def check(text: str) -> str:
        p = Path(text)
        if extensions is not None:
            exts = tuple(extensions() if callable(extensions) else extensions)
            if p.suffix.lower() not in exts:
                raise argparse.ArgumentTypeError(
                    f'{text}: unsupported file extension {p.suffix or "(none)"!r}; use one of {", ".join(exts)}')
        if p.is_dir():
            raise argparse.ArgumentTypeError(f'{text} is a directory, expected a file name')
        parent = p.parent if str(p.parent) else Path('.')
        if create_parent:
            while not parent.exists():
                parent = parent.parent if str(parent.parent) not in ('', str(parent)) else Path('.')
            if not parent.is_dir():
                raise argparse.ArgumentTypeError(f'{text}: {parent} is a file, expected a folder')
        if not parent.is_dir():
            raise argparse.ArgumentTypeError(f'{text}: directory {parent} does not exist')
        why = _cannot_create_in(parent)
        if why is not None:
            raise argparse.ArgumentTypeError(f'{text}: directory {parent} is not writable: {why}')
        return text
    return check


def open_for_writing(path: str | Path) -> Path:
    """``path`` with its parent folders made (an :func:`output_file` with ``create_parent``)."""
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    return p


EXIT_INTERRUPTED = 130      # 128 + SIGINT, as a shell reports a program stopped by Ctrl-C


def interrupted(prog: str, kept: str = '') -> int:
    """Ctrl-C in a tool: one line (what was kept, if anything) instead of a traceback; the exit code."""
    print(f'{prog}: interrupted (Ctrl-C)' + (f'; {kept}' if kept else ''), file=sys.stderr, flush=True)
    return EXIT_INTERRUPTED


def plot_extensions() -> tuple[str, ...]:
    """File extensions matplotlib can save a figure to (its own registry)."""
    from matplotlib.backend_bases import FigureCanvasBase
    return tuple(sorted('.' + e for e in FigureCanvasBase.get_supported_filetypes()))


def add_overlay_option(parser: argparse.ArgumentParser, help_text: str | None = None) -> None:
    """``--overlay YAML`` (repeatable): robot-description overlays to read, applied in order."""
    parser.add_argument(OVERLAY_FLAG, action='append', default=[], metavar='YAML', type=existing_file,
                        help=help_text or 'robot-description overlay to apply (e.g. injected effects or a '
                                          'fitted discrepancy result); repeatable, applied in order')


def add_no_progress_option(parser: argparse.ArgumentParser) -> None:
    """``--no-progress``: no progress bar (they go to stderr)."""
    parser.add_argument(NO_PROGRESS_FLAG, dest='progress', action='store_false',
                        help='no progress bar (progress bars go to stderr)')
