"""YAML files a user edits: where they are (symlinks resolved) and what is wrong in one, on one line."""
from __future__ import annotations

from pathlib import Path

import yaml


def source_path(path: str | Path) -> Path:
    """The file a user edits: ``path`` with symlinks resolved (a ``--symlink-install`` build holds
    links to the source tree; messages name the source, not the copy under build/ or install/)."""
    p = Path(path)
    try:
        return p.resolve() if p.is_symlink() or any(q.is_symlink() for q in p.parents) else p
    except OSError:
        return p


def yaml_problem(exc: yaml.YAMLError) -> str:
    """What is wrong in a YAML file and where, on one line ('line 3, column 1: expected ...'),
    without PyYAML's multi-line excerpt and its '"<unicode string>"' stream name."""
    mark = getattr(exc, 'problem_mark', None)
    problem = ' '.join(str(getattr(exc, 'problem', None) or exc).split())
    context = ' '.join(str(getattr(exc, 'context', None) or '').split())
    where = f'line {mark.line + 1}, column {mark.column + 1}: ' if mark is not None else ''
    return where + (f'{context}: ' if context else '') + problem
