"""Workspace lint: no node logs through a call site whose severity varies.

rclpy remembers the severity of each logging call site and raises ``ValueError: Logger severity
cannot be changed between calls`` the second time a site is hit with another level; in a worker
thread that kills the thread (the driver's bus loop once died on its first fault that way). The
patterns ``getattr(logger, level)(text)`` and ``(logger.warn if ok else logger.error)(text)`` are
therefore forbidden in every package's Python files.
"""
import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = sorted(p for p in ROOT.iterdir() if (p / 'package.xml').is_file())


def _is_loggerish(node: ast.AST) -> bool:
    src = ast.unparse(node).lower()
    return 'log' in src


def varying_severity_calls(source: str, filename: str = '<string>') -> list[tuple[int, str]]:
    """(line, code) of every call whose callee is a logger method chosen at run time."""
    found = []
    for node in ast.walk(ast.parse(source, filename)):
        if not isinstance(node, ast.Call):
            continue
        f = node.func
        if isinstance(f, ast.Call) and isinstance(f.func, ast.Name) and f.func.id == 'getattr' and f.args \
                and _is_loggerish(f.args[0]) and not (len(f.args) > 1 and isinstance(f.args[1], ast.Constant)):
            found.append((node.lineno, ast.unparse(node)))
        elif isinstance(f, ast.IfExp) and (_is_loggerish(f.body) or _is_loggerish(f.orelse)):
            found.append((node.lineno, ast.unparse(node)))
        elif isinstance(f, ast.Subscript) and _is_loggerish(f.value):     # {...}[level](text)
            found.append((node.lineno, ast.unparse(node)))
    return found


def test_the_lint_catches_each_pattern():
    bad = ('getattr(self.get_logger(), level)(text)\n'
           '(self.get_logger().warn if ok else self.get_logger().error)(msg)\n'
           '(logger.info if ok else logger.error)(msg)\n'
           'getattr(self._logger, lvl)(text)\n'
           '{"info": log.info, "error": log.error}[level](text)\n')
    assert [line for line, _ in varying_severity_calls(bad)] == [1, 2, 3, 4, 5]
    good = ('self.get_logger().warn(text)\n'
            'getattr(self, name)(x)\n'
            'logger.error(a if ok else b)\n'
            'getattr(logger, "info")(text)\n')
    assert varying_severity_calls(good) == []


def test_no_package_logs_through_a_call_site_of_varying_severity():
    assert PACKAGES, f'no ROS packages found under {ROOT}'
    offenders = []
    for pkg in PACKAGES:
        for path in sorted(pkg.rglob('*.py')):
            if any(part in ('build', 'install', 'log', '.venv') for part in path.relative_to(ROOT).parts):
                continue
            for line, code in varying_severity_calls(path.read_text(), str(path)):
                offenders.append(f'{path.relative_to(ROOT)}:{line}: {code}')
    assert not offenders, ('logging call sites whose severity varies (rclpy raises on the second call with '
                           'another level; use one call site per severity):\n' + '\n'.join(offenders))
