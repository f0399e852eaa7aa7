"""The house's sizes (docs/architecture.md): a module does one job and a reader finds its
parts, so no module outside the tests is over 800 lines and no function over 80."""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
PACKAGES = ("server", "planner_client", "shared", "m3p2i", "scripts")
MAX_FILE_LINES = 800
MAX_FUNCTION_LINES = 80


def _sources() -> list[Path]:
    return sorted(p for pkg in PACKAGES for p in (ROOT / pkg).rglob("*.py"))


def too_long(path: Path, root: Path = ROOT) -> list[str]:
    """``path``'s faults against the sizes: the file, then each function, by name and lines."""
    text = path.read_text(encoding="utf-8")
    name, n = path.relative_to(root), text.count("\n")
    faults = [f"{name}: {n} lines"] if n > MAX_FILE_LINES else []
    for node in ast.walk(ast.parse(text)):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            lines = node.end_lineno - node.lineno + 1
            if lines > MAX_FUNCTION_LINES:
                faults.append(f"{name}:{node.lineno} {node.name}: {lines} lines")
    return faults


def test_no_module_or_function_is_over_its_size():
    sources = _sources()
    assert len(sources) > 100  # the packages were found
    faults = [f for p in sources for f in too_long(p)]
    assert not faults, "split these (one job each):\n" + "\n".join(faults)


def test_the_size_check_sees_a_long_function_and_a_long_file(tmp_path):
    probe = tmp_path / "probe.py"
    body = "\n".join(f"    x{i} = {i}" for i in range(MAX_FUNCTION_LINES))
    probe.write_text(f"def f():\n{body}\n", encoding="utf-8")
    assert too_long(probe, tmp_path) == [f"probe.py:1 f: {MAX_FUNCTION_LINES + 1} lines"]
    probe.write_text("x = 1\n" * MAX_FILE_LINES, encoding="utf-8")
    assert too_long(probe, tmp_path) == []  # at the bound: allowed
    probe.write_text("x = 1\n" * (MAX_FILE_LINES + 1), encoding="utf-8")
    assert too_long(probe, tmp_path) == [f"probe.py: {MAX_FILE_LINES + 1} lines"]
