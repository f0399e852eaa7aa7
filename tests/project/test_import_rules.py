"""The package layout's import rules (docs/architecture.md).

``server`` and ``planner_client`` meet only over the wire (or in one process, where the caller
hands the world a planner: ``server.inprocess``): neither imports the other, nor ``m3p2i``, the
command that composes them. ``shared`` is the contract both processes need and imports none of
the three, nor the heavy libraries of the tools (optuna, ray, viser, matplotlib, imageio).
``server.evaluation`` (the world's judgement of an episode, which the tools read back from its
log) imports nothing else of ``server``, so reading a log never starts a world. ``m3p2i`` may
import the three others. Every ``import`` in every module counts, including those inside
functions.
"""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
PACKAGES = ("server", "planner_client", "shared", "m3p2i")

# (importer prefix, forbidden import prefix): a module whose dotted name starts with the first
# may not import a module whose dotted name starts with the second.
TOOL_LIBRARIES = ("optuna", "ray", "viser", "matplotlib", "imageio")
FORBIDDEN = (
    ("server", "planner_client"),
    ("server", "m3p2i"),
    ("planner_client", "server"),
    ("planner_client", "m3p2i"),
    ("shared", "server"),
    ("shared", "planner_client"),
    ("shared", "m3p2i"),
    *(("shared", lib) for lib in TOOL_LIBRARIES),
)
EVALUATION = "server.evaluation"


def module_name(path: Path, root: Path) -> str:
    parts = list(path.relative_to(root).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def imports(path: Path, root: Path) -> set[str]:
    """Dotted names of every module ``path`` imports (relative imports made absolute)."""
    tree = ast.parse(path.read_text(), str(path))
    package = module_name(path, root)
    if path.name != "__init__.py":
        package = package.rpartition(".")[0]
    out: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")[: len(package.split(".")) - node.level + 1]
                prefix = ".".join(base + ([node.module] if node.module else []))
            else:
                prefix = node.module or ""
            out.add(prefix)
            # `from server import evaluation` imports the module server.evaluation
            out.update(f"{prefix}.{a.name}" for a in node.names)
    return out


def _within(name: str, prefix: str) -> bool:
    return name == prefix or name.startswith(prefix + ".")


def _evaluation_may_not(imported: str) -> bool:
    return _within(imported, "server") and not _within(imported, EVALUATION)


def violations(root: Path) -> list[str]:
    found = []
    for package in PACKAGES:
        for path in sorted((root / package).rglob("*.py")):
            importer = module_name(path, root)
            for imported in sorted(imports(path, root)):
                rules = [(a, b) for a, b in FORBIDDEN if _within(importer, a)]
                broken = any(_within(imported, forbidden) for _, forbidden in rules)
                if _within(importer, EVALUATION) and _evaluation_may_not(imported):
                    broken = True
                if broken:
                    found.append(f"{path.relative_to(root)}: {importer} imports {imported}")
    return found


def test_the_project_keeps_its_import_rules():
    assert violations(ROOT) == []


def test_every_package_is_scanned():
    # a rule over an empty set of files would pass for the wrong reason
    for package in PACKAGES:
        assert list((ROOT / package).rglob("*.py")), package
    assert (ROOT / "m3p2i" / "cli.py").is_file()
    assert (ROOT / "server" / "evaluation" / "metrics.py").is_file()


def _write(root: Path, rel: str, text: str) -> None:
    path = root / rel
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)


def test_the_checker_finds_each_kind_of_violation(tmp_path):
    for package in ("server", "planner_client", "shared", "m3p2i", "server/evaluation"):
        _write(tmp_path, f"{package}/__init__.py", "")
    _write(tmp_path, "server/app.py", "from planner_client.loop import PlannerClient\n")
    _write(tmp_path, "server/cli.py", "from m3p2i.launch import run_episode\n")
    _write(tmp_path, "planner_client/loop.py", "def f():\n    import server.world\n")
    _write(tmp_path, "shared/scenario.py", "from m3p2i import bench\n")
    _write(tmp_path, "shared/scene.py", "from server.evaluation.metrics import x\n")
    _write(tmp_path, "shared/geometry.py", "def f():\n    import matplotlib.pyplot\n")
    _write(tmp_path, "server/evaluation/metrics.py", "from ...m3p2i.launch import y\n")
    _write(
        tmp_path,
        "m3p2i/cli.py",
        "from server.evaluation import log\nfrom server.inprocess import build_episode\n"
        "from planner_client.build import build_controller\nimport optuna\n",
    )
    _write(tmp_path, "server/evaluation/log_reader.py", "from server.app import WorldServer\n")
    _write(tmp_path, "shared/protocol.py", "import planner_client.controller\n")
    found = "\n".join(violations(tmp_path))
    assert "server.app imports planner_client.loop" in found
    assert "server.cli imports m3p2i.launch" in found
    assert "planner_client.loop imports server.world" in found
    assert "shared.scenario imports m3p2i" in found
    assert "shared.scene imports server.evaluation.metrics" in found
    assert "shared.geometry imports matplotlib.pyplot" in found
    assert "server.evaluation.metrics imports m3p2i.launch" in found
    assert "m3p2i.cli" not in found  # the command may import everything
    assert "server.evaluation.log_reader imports server.app" in found
    assert "shared.protocol imports planner_client.controller" in found


def test_the_world_server_starts_without_torch():
    # torch is the planner's: importing it would cost every server start ~1.5 s (docs/speed.md)
    import subprocess
    import sys

    code = (
        "import sys, server.cli; "
        "print(sorted(m for m in sys.modules if m.split('.')[0] == 'torch')[:3])"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, check=True
    ).stdout.strip()
    assert out == "[]", f"server.cli imports torch: {out}"
