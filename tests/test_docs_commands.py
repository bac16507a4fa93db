"""The commands README.md and docs/ name exist as written: every ``ros2 run PKG EXE`` and
``./hexapod run PKG EXE`` is an installed executable, every ``./hexapod NAME`` a command of the
script; and the discrepancy tool's first documented example runs on a fresh clone (its output
folder ``out/`` does not exist there)."""
import os
import re
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = [ROOT / 'README.md', ROOT / 'bags' / 'README.md', *sorted((ROOT / 'docs').glob('*.md'))]
BUILTIN = {'setup', 'build', 'test', 'run', 'env', 'shell', 'help'}


def _shortcuts() -> dict:
    table = (ROOT / 'hexapod').read_text().split("SHORTCUTS='", 1)[1].split("'", 1)[0]
    return {f[0]: (f[1], f[2]) for f in (line.split() for line in table.splitlines()) if len(f) >= 3}


def _mentions(pattern: str) -> list[tuple[str, tuple]]:
    return [(f'{doc.relative_to(ROOT)}: {m.group(0)}', m.groups()) for doc in DOCS
            for m in re.finditer(pattern, doc.read_text())]


def _installed(pkg: str, exe: str) -> bool:
    path = ROOT / 'install' / pkg / 'lib' / pkg / exe
    return path.is_file() and os.access(path, os.X_OK)


def test_every_run_command_in_the_docs_is_installed():
    runs = _mentions(r'(?:ros2 run|\./hexapod run) (hexapod_[a-z]+) ([a-z_]+)')
    assert runs
    missing = [where for where, (pkg, exe) in runs if not _installed(pkg, exe)]
    assert not missing, missing


def test_every_hexapod_command_in_the_docs_exists():
    known = BUILTIN | set(_shortcuts())
    uses = _mentions(r'\./hexapod ([a-z][a-z_-]*)')
    assert uses
    unknown = [where for where, (name,) in uses if name not in known]
    assert not unknown, unknown
    for name, (pkg, exe) in _shortcuts().items():
        assert _installed(pkg, exe), f'./hexapod {name}: {pkg} {exe} is not installed'


def test_the_discrepancy_example_creates_its_output_folder(tmp_path):
    doc = (ROOT / 'docs' / 'discrepancy.md').read_text()
    line = next(ln for ln in doc.splitlines() if ln.startswith('./hexapod discrepancy bags/discrepancy_demo '))
    args = line.split()[2:]
    assert any(a.startswith('out/') for a in args), line
    (tmp_path / 'bags').symlink_to(ROOT / 'bags')
    res = subprocess.run([str(ROOT / 'install' / 'hexapod_sim' / 'lib' / 'hexapod_sim' / 'discrepancy'), *args,
                          '--no-progress'], cwd=tmp_path, capture_output=True, text=True, timeout=600)
    assert res.returncode == 0, res.stderr
    for a in args:
        if a.startswith('out/'):
            assert (tmp_path / a).is_file(), a


@pytest.mark.parametrize('flag, name', [('--json', 'r.json'), ('--plot', 'p.png')])
def test_analyse_creates_the_folder_of_its_outputs(tmp_path, flag, name):
    out = tmp_path / 'new' / 'folder' / name
    res = subprocess.run([str(ROOT / 'install' / 'hexapod_locomotion' / 'lib' / 'hexapod_locomotion' / 'analyse'),
                          str(ROOT / 'bags' / 'tripod_blocks_fixed'), flag, str(out), '--no-progress'],
                         capture_output=True, text=True, timeout=600)
    assert res.returncode == 0, res.stderr
    assert out.is_file()
