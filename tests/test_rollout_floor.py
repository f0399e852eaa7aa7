"""scripts/rollout_floor.py: the bare rollout of a planner's own model, with parts of its physics
switched off, really runs those models (what it prints is timing, not tested here)."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import mujoco
from typer.testing import CliRunner

ROOT = Path(__file__).resolve().parents[1]
spec = importlib.util.spec_from_file_location("rollout_floor", ROOT / "scripts" / "rollout_floor.py")
floor = importlib.util.module_from_spec(spec)
spec.loader.exec_module(floor)


def test_variants_switch_off_what_they_name(monkeypatch):
    seen = []
    real = floor.mj_rollout.Rollout.rollout

    def spy(self, models, datas, x0, ctrl, **kw):
        seen.append((models.opt.disableflags, ctrl.shape))
        return real(self, models, datas, x0, ctrl, **kw)
    monkeypatch.setattr(floor.mj_rollout.Rollout, "rollout", spy)
    times = floor.measure("navigation", samples=6, horizon=4, nthread=1, rounds=1)
    assert list(times) == list(floor.VARIANTS) and all(t > 0 for t in times.values())
    base = min(f for f, _ in seen)                 # the planner's own flags
    assert {f for f, _ in seen} == {base | bit for bit in floor.VARIANTS.values()}
    assert floor.VARIANTS["no constraints"] == int(mujoco.mjtDisableBit.mjDSBL_CONSTRAINT)
    assert {shape for _, shape in seen} == {(6, 4, 2)}


def test_cli_prints_every_variant():
    result = CliRunner().invoke(floor.app, ["-s", "navigation", "--samples", "4", "--horizon",
                                            "3", "--rounds", "1", "--threads", "1"],
                                 env={"COLUMNS": "200"})
    assert result.exit_code == 0, result.output
    for variant in floor.VARIANTS:
        assert variant in result.output
