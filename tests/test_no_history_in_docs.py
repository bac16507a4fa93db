"""Workspace lint: code and docs describe the project as it is, not how it came to be.

A reader has no issue tracker and was not there when a figure was measured, so comments, docstrings
and docs name no issue numbers ("issue 16", "issues 15 and 18") and no working sessions ("the
previous session", "other sessions loading the machine"): a figure states the command that
reproduces it and the date it was measured, and development history belongs in the git log. The
word "session" is refused in every sense, so that a history sentence cannot pass as a software term;
say "the live view", "the shell", "the run" instead.

Checked: every package, tests/, tools/, docs/, the entry point, CI, requirements/, README.md and
bags/README.md, in the file types that carry prose (the build, install and virtual-environment
trees, third-party node_modules and this file excluded).
"""
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PATTERN = re.compile(r'issue [0-9]|issues? [0-9]|session', re.IGNORECASE)
SUFFIXES = {'.py', '.md', '.yaml', '.yml', '.xml', '.cfg', '.txt', '.msg', '.srv', '.mjs', '.ini', '.toml', '.sh'}
TREES = ['tests', 'tools', 'docs', 'requirements', '.ci']
FILES = ['README.md', 'bags/README.md', 'hexapod', 'pytest.ini', '.ci/run']
SKIP_DIRS = {'.venv', 'build', 'install', 'log', 'node_modules', '__pycache__', '.git', '.pytest_cache'}


def history_hits(text: str) -> list[tuple[int, str]]:
    """(line number, line) of every line that refers to an issue number or a session."""
    return [(n, line.strip()) for n, line in enumerate(text.splitlines(), 1) if PATTERN.search(line)]


def checked_files() -> list[Path]:
    trees = sorted(p for p in ROOT.glob('hexapod_*') if p.is_dir()) + [ROOT / t for t in TREES]
    found = {ROOT / f for f in FILES if (ROOT / f).is_file()}
    for tree in trees:
        if not tree.is_dir():
            continue
        for path in tree.rglob('*'):
            rel = path.relative_to(ROOT)
            if path.is_file() and path.suffix in SUFFIXES and not SKIP_DIRS.intersection(rel.parts[:-1]):
                found.add(path)
    found.discard(Path(__file__).resolve())
    return sorted(found)


def test_the_lint_catches_each_form():
    text = ('measured in issue 16\n'
            'see Issues 15 and 18\n'
            'the previous session had other sessions running\n'
            'a tissue 3 cm thick\n'              # caught: the check is plain text, like the grep
            'the table4 trials on the mockup (2026-11-25)\n')
    assert [n for n, _ in history_hits(text)] == [1, 2, 3, 4]


def test_the_checked_files_cover_code_and_docs():
    rel = {p.relative_to(ROOT).as_posix() for p in checked_files()}
    for expected in ('README.md', 'docs/architecture.md', 'hexapod_locomotion/hexapod_locomotion/core/controller.py',
                     'hexapod_model/hexapod_model/__init__.py', 'tests/test_package_dependencies.py'):
        assert expected in rel, expected
    assert not any(r.startswith(('build/', 'install/', '.venv/')) or '/node_modules/' in r for r in rel)
    assert 'tests/test_no_history_in_docs.py' not in rel


def test_no_issue_numbers_or_sessions_in_code_and_docs():
    hits = []
    for path in checked_files():
        try:
            text = path.read_text(encoding='utf-8')
        except UnicodeDecodeError:
            continue
        hits += [f'{path.relative_to(ROOT)}:{n}: {line}' for n, line in history_hits(text)]
    assert not hits, ('code and docs must describe the project as it is (no issue numbers, no sessions; '
                      'a figure gives its command and date):\n' + '\n'.join(hits))
