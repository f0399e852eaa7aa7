"""scripts.measure.rollout_parts (scripts/rollout_floor.py): the bare rollout of a planner's own
model, with parts of its physics switched off, really runs those models (what it prints is
timing, not tested here)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import mujoco
from rich.console import Console

from scripts.measure import rollout_parts as floor
from tests.helpers import ENV

ROOT = Path(__file__).resolve().parents[2]


def test_variants_switch_off_what_they_name(monkeypatch):
    seen = []
    real = floor.mj_rollout.Rollout.rollout

    def spy(self, models, datas, x0, ctrl, **kw):
        seen.append((models.opt.disableflags, ctrl.shape))
        return real(self, models, datas, x0, ctrl, **kw)

    monkeypatch.setattr(floor.mj_rollout.Rollout, "rollout", spy)
    times = floor.measure("navigation", samples=6, horizon=4, nthread=1, rounds=1)
    assert list(times) == list(floor.VARIANTS) and all(t > 0 for t in times.values())
    base = min(f for f, _ in seen)  # the planner's own flags
    assert {f for f, _ in seen} == {base | bit for bit in floor.VARIANTS.values()}
    assert floor.VARIANTS["no constraints"] == int(mujoco.mjtDisableBit.mjDSBL_CONSTRAINT)
    assert {shape for _, shape in seen} == {(6, 4, 2)}


def test_the_table_has_every_variant():
    console = Console(width=200, record=True)
    console.print(floor.floor_table(["navigation"], samples=4, horizon=3, nthread=1, rounds=1))
    text = console.export_text()
    for variant in floor.VARIANTS:
        assert variant in text


def test_the_script_prints_the_table():
    run = subprocess.run(
        [
            sys.executable,
            str(ROOT / "scripts" / "rollout_floor.py"),
            "-s",
            "navigation",
            "--samples",
            "4",
            "--horizon",
            "3",
            "--rounds",
            "1",
            "--threads",
            "1",
        ],
        capture_output=True,
        text=True,
        timeout=300,
        env={**ENV, "COLUMNS": "200"},
        cwd=ROOT,
    )
    assert run.returncode == 0, run.stderr
    assert all(variant in run.stdout for variant in floor.VARIANTS), run.stdout
