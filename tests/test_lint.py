"""The pinned linter finds nothing: ruff (requirements/py.txt) with the rule set of ruff.toml (pycodestyle,
pyflakes, import order) over every package, test and tool of the workspace."""
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_ruff_finds_nothing():
    ruff = Path(sys.executable).parent / 'ruff'
    assert ruff.exists(), f'{ruff}: not installed; ./hexapod setup installs requirements/py.txt'
    p = subprocess.run([str(ruff), 'check', '--no-cache', '--output-format', 'concise', str(ROOT)], cwd=ROOT,
                       capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stdout + p.stderr
