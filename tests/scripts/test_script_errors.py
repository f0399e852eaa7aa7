"""The measurement scripts meet a wrong input with one line that names it and says what was
expected, and a non-zero exit, not a traceback."""

from __future__ import annotations

import importlib.util
import subprocess
import sys
from pathlib import Path

import pytest

from tests.helpers import ENV

ROOT = Path(__file__).resolve().parents[2]


def _script(name: str, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, str(ROOT / "scripts" / name), *args],
        capture_output=True,
        text=True,
        env={**ENV, "COLUMNS": "200"},
        timeout=120,
    )


@pytest.mark.parametrize(
    "script, args, said",
    [
        ("benchmark.py", ["-s", "no_such_scenario"], "no_such_scenario: no such scenario"),
        ("benchmark.py", ["--backend", "foo"], "'foo': expected one of mujoco, warp"),
        ("benchmark.py", ["-n", "5"], "greater than or equal to 20"),  # timed 20 anyway
        ("benchmark.py", ["--samples", "0,10"], "expected integers >= 1"),
        ("startup.py", ["-s", "duo_corridor", "--no-compile"], "starts a planner per robot"),
        ("soak.py", ["--scenario", "no_such_scenario"], "no_such_scenario: no such scenario"),
        ("rollout_floor.py", ["-s", "no_such_scenario"], "no_such_scenario: no such scenario"),
        ("view_overhead.py", ["-n", "0"], "expected an integer >= 1, got 0"),
    ],
)
def test_a_script_refuses_a_wrong_option_before_measuring(script, args, said):
    run = _script(script, *args)
    assert run.returncode == 2, run.stdout + run.stderr
    assert said in " ".join(run.stderr.split()), run.stderr  # rich wraps its box's lines
    assert "Traceback" not in run.stderr


def test_soak_report_of_a_missing_file_names_it(tmp_path):
    run = _script("soak.py", "--report", str(tmp_path / "none.json"))
    assert run.returncode == 2
    assert f"--report: no file {tmp_path / 'none.json'}" in run.stderr
    assert "Traceback" not in run.stderr


def test_soak_update_of_a_block_naming_a_missing_file_names_both(tmp_path):
    doc = tmp_path / "doc.md"
    doc.write_text("<!-- soak gone.json -->\nold\n<!-- end of soak -->\n")
    run = _script("soak.py", "--update", str(doc))
    assert run.returncode == 2 and "<!-- soak gone.json -->: no file" in run.stderr
    assert doc.read_text().count("old") == 1  # left as it was


def test_view_overhead_stops_at_a_run_that_fails_and_shows_why():
    run = _script("view_overhead.py", "--scenario", "no_such_scenario", "-n", "1")
    assert run.returncode == 1
    assert "exited with code 2" in run.stderr and "no_such_scenario" in run.stderr
    assert "Traceback" not in run.stderr


@pytest.mark.skipif(
    importlib.util.find_spec("pytorch_mppi") is not None, reason="pytorch_mppi is installed"
)
def test_benchmark_mppi_says_how_to_install_its_peer():
    run = _script("benchmark_mppi.py", "--seeds", "1")
    assert run.returncode == 1 and "pip install pytorch-mppi" in run.stderr
    assert "Traceback" not in run.stderr
