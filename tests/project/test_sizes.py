"""The house's sizes (docs/architecture.md): a module does one job and a reader finds its
parts, so no module outside the tests is over 800 lines and no function over 80; and
``shared/``, the contract both processes need and nothing else, is at most 6,500 lines."""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
PACKAGES = ("server", "planner_client", "shared", "m3p2i", "scripts")
MAX_FILE_LINES = 800
MAX_FUNCTION_LINES = 80
MAX_SHARED_LINES = 6_500


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


def shared_lines(root: Path = ROOT) -> int:
    """Lines of every ``*.py`` under ``root/shared``, as ``wc -l`` counts them (newlines)."""
    return sum(p.read_text(encoding="utf-8").count("\n") for p in (root / "shared").rglob("*.py"))


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


def test_shared_holds_the_contract_and_nothing_else():
    n = shared_lines()
    assert n > 1000  # the package was found
    assert n <= MAX_SHARED_LINES, (
        f"shared/ is {n} lines, over {MAX_SHARED_LINES}: it is the contract both processes need "
        "and nothing else (docs/architecture.md); move what only one side (or only the m3p2i "
        "command) uses into that side's package: server/, planner_client/ or m3p2i/"
    )


def test_the_shared_count_counts_lines_as_wc_does(tmp_path):
    (tmp_path / "shared" / "scenario").mkdir(parents=True)
    (tmp_path / "shared" / "a.py").write_text("x = 1\n" * 3, encoding="utf-8")
    (tmp_path / "shared" / "scenario" / "b.py").write_text("y = 2\nz = 3", encoding="utf-8")
    (tmp_path / "shared" / "notes.md").write_text("not code\n", encoding="utf-8")
    assert shared_lines(tmp_path) == 4  # wc -l: the last line without its newline is not one
