"""Repairing bags a recording left unfinished: :func:`reindex_bag` (a power cut, a copy taken
half-written) and :func:`recover_bag` (every readable message into a new bag). A write error is
handled by the writer itself (:func:`hexapod_sim.bagio.end_cut.end_cut_file`).

:func:`reindex_bag` (``rosbag2 reindex`` in ROS 2 terms) rebuilds a bag whose files lack their
footer or index, or whose ``metadata.yaml`` is missing or lies: every readable message is copied
into one new, properly closed MCAP file and ``metadata.yaml`` is written from what the file holds.
The new files are written next to the old ones and only then replace them, so a repair that is
itself cut off leaves the bag as it was.
"""
from __future__ import annotations

import os
import shutil
import warnings
from dataclasses import dataclass
from pathlib import Path

from hexapod_sim.bagio.common import BagError, BagWarning
from hexapod_sim.bagio.reader import BagReader, copy_messages
from hexapod_sim.bagio.writer import BagWriter

REINDEX_TMP = '.reindex'          # the rebuilt bag is written here inside the bag directory


@dataclass
class ReindexResult:
    path: Path
    rebuilt: bool           # False: the bag was complete, nothing was changed
    messages: int           # messages in the bag afterwards
    duration_s: float       # log time covered afterwards
    problems: list          # what the reader found wrong before (one line each)

    def line(self) -> str:
        if not self.rebuilt:
            return (f'{self.path}: complete ({self.messages} messages, {self.duration_s:.1f} s); '
                    'nothing to rebuild')
        return (f'{self.path}: rebuilt: {self.messages} messages, {self.duration_s:.1f} s of log time '
                f'(was: {self.problems[0]}' + (f'; and {len(self.problems) - 1} more problem(s)'
                                                if len(self.problems) > 1 else '') + ')')


def _read(path: Path, ignore_metadata: bool = False) -> BagReader:
    with warnings.catch_warnings():
        warnings.simplefilter('ignore', BagWarning)
        return BagReader(path, ignore_metadata=ignore_metadata)


def reindex_bag(path: str | os.PathLike, *, force: bool = False) -> ReindexResult:
    """Rebuild the bag directory ``path`` into one complete MCAP file and a ``metadata.yaml`` that
    matches it (unless it is complete already and ``force`` is False). Raises :class:`BagError` if
    nothing in it is readable."""
    p = Path(path)
    if p.is_file():
        raise BagError(f'{p}: reindex works on a bag directory (the folder holding metadata.yaml and the '
                       '.mcap files), not on a file')
    if not p.is_dir():
        raise BagError(f'{p}: no such bag directory')
    tmp_root = p / REINDEX_TMP
    if tmp_root.exists():                   # left by a reindex that was cut off: start over
        shutil.rmtree(tmp_root)
    problems = []
    try:
        reader = _read(p)
    except BagError as exc:                 # e.g. metadata.yaml lists files that are not there
        problems.append(str(exc))
        reader = None
    if reader is not None:
        problems.extend(reader.warnings)
        unlisted = _unlisted_files(p, reader)
        if unlisted:
            problems.append(f'{len(unlisted)} .mcap file(s) not listed in metadata.yaml: {unlisted}')
        if reader.complete and reader.metadata is not None and not unlisted and not force:
            return ReindexResult(p, False, reader.message_count, (reader.end_ns - reader.start_ns) * 1e-9, [])
    if reader is None or reader.metadata is None or problems:
        reader = _read(p, ignore_metadata=True)       # the .mcap files themselves, whatever metadata.yaml says
    old_files = sorted(x.name for x in p.iterdir() if x.suffix == '.mcap' and x.is_file())
    name = p.resolve().name
    tmp = tmp_root / name
    custom = (reader.metadata or {}).get('custom_data') or None
    n = 0
    try:
        with BagWriter(tmp, custom_data=custom if isinstance(custom, dict) else None) as w:
            n = copy_messages(reader, w)
        new_mcap = tmp / f'{name}_0.mcap'
        os.replace(new_mcap, p / new_mcap.name)
        for old in old_files:
            if old != new_mcap.name and (p / old).exists():
                (p / old).unlink()
        os.replace(tmp / 'metadata.yaml', p / 'metadata.yaml')
    finally:
        shutil.rmtree(tmp_root, ignore_errors=True)
    after = _read(p)
    return ReindexResult(p, True, n, (after.end_ns - after.start_ns) * 1e-9,
                         problems or ['metadata.yaml missing or not matching the files'])


def _unlisted_files(p: Path, reader: BagReader) -> list[str]:
    if reader.metadata is None:
        return []
    listed = {s.path.name for s in reader._scans}
    return sorted(x.name for x in p.iterdir() if x.suffix == '.mcap' and x.is_file() and x.name not in listed)


def recover_bag(src: str | os.PathLike, dst: str | os.PathLike, **writer_kw) -> int:
    """Copy every readable message of ``src`` (e.g. a recording cut off by a crash, which other
    tools such as rosbags refuse without its MCAP footer) into a new, properly closed bag ``dst``.
    Topic definitions and QoS are taken from ``src``. Returns the number of messages copied."""
    reader = BagReader(src)
    with BagWriter(dst, **writer_kw) as w:
        return copy_messages(reader, w)
