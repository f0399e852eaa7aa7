"""Values a scenario file may hold that no planner can afford, refused at load with the file, the
key, the value and the bound: a million model variants, a guide's grid of a hundred million
cells, a goal outside the arena; and a faulty guide: section reported once, not again by every
term that follows its sub-goal."""

from __future__ import annotations

import copy

import pytest
import yaml

from planner_client.planner_check import scenario_errors
from shared.config import ConfigError, load_yaml
from shared.scenario import find_scenario, parse_scenario
from shared.scenario.guide import GUIDE_MAX_CELLS, grid_cells
from shared.scenario.variants import MAX_VARIANT_ROLLOUTS, MAX_VARIANTS


def _raw(name: str) -> dict:
    return copy.deepcopy(load_yaml(find_scenario(name)))


def _refused(raw: dict, pattern: str) -> str:
    with pytest.raises(ConfigError, match=pattern) as info:
        parse_scenario(raw, "s.yaml")
    return str(info.value)


@pytest.mark.parametrize("spread", ["split", "all", "identified"])
def test_more_model_variants_than_the_bound_are_refused(spread):
    raw = _raw("pull_lab_variants")
    variants = raw["planner"]["model"]["variants"]
    variants.pop("aggregate", None)
    variants.update(spread=spread, count=1_000_000)
    text = _refused(raw, r"s.yaml: planner.model.variants.count")
    assert f"[1, {MAX_VARIANTS}]" in text and "1000000" in text
    variants["count"] = MAX_VARIANTS
    raw["planner"]["samples"] = MAX_VARIANTS  # a split needs a sample per variant
    if spread == "all":
        raw["planner"]["samples"] = MAX_VARIANT_ROLLOUTS // MAX_VARIANTS
    parse_scenario(raw, "s.yaml")


def test_spread_all_is_bounded_by_its_rollouts_per_iteration():
    raw = _raw("pull_lab_variants")
    variants = raw["planner"]["model"]["variants"]
    variants.update(spread="all", count=200)
    raw["planner"]["samples"] = 400  # 80,000 rollouts of every mode in every iteration
    text = _refused(raw, r"planner.model.variants.count: 200 variants x planner.samples = 400")
    assert "80,000 rollouts" in text and f"{MAX_VARIANT_ROLLOUTS:,}" in text


def test_a_guide_grid_finer_than_the_bound_is_refused_naming_the_finest_resolution():
    raw = _raw("navigation_trap_guided")  # an 8 m arena
    raw["guide"]["resolution"] = 0.0001
    text = _refused(raw, r"s.yaml: guide.resolution: a grid of [\d,]+ cells over the world's 8 x 8")
    assert f"at most {GUIDE_MAX_CELLS:,} cells: metres >= 0.020" in text
    raw["guide"]["resolution"] = 0.021
    sc = parse_scenario(raw, "s.yaml")
    assert grid_cells(0.021, sc.world.span()) <= GUIDE_MAX_CELLS


def test_an_object_outside_the_arena_is_refused():
    raw = _raw("navigation")
    goal = next(o for o in raw["world"]["objects"] if o["name"] == "goal")
    goal["pos"] = [6.0, 0.0, 0.0]
    text = _refused(raw, r"s.yaml: world.objects\[\d+\].pos: outside the arena")
    assert "±4 m" in text and "[6.0, 0.0, 0.0]" in text


def test_a_faulty_guide_is_reported_once(tmp_path):
    # its terms follow site:guide; before, each of them added "no site named 'guide'"
    raw = _raw("navigation_trap_guided")
    raw["guide"]["resolutio"] = 0.1
    path = tmp_path / "trap.yaml"
    path.write_text(yaml.safe_dump(raw))
    errors = [str(e) for e in scenario_errors(path)]
    assert len(errors) == 1 and "guide.resolutio: unknown key" in errors[0], errors


def test_guide_for_names_what_it_may_be_without_a_dangling_comma():
    raw = _raw("navigation_trap_guided")
    raw["guide"]["for"] = "goal"  # a marker: fixed
    text = _refused(raw, r"guide.for: not the robot or a free object")
    assert "expected robot (the world has no free object))" in text, text


@pytest.mark.parametrize("key", ["eta_bounds", "u_max", "noise_sigma"])
def test_an_integer_no_float_holds_is_refused_in_the_mppi_section(key):
    # 10**400 reached math.isnan and raised OverflowError (found by tests/shared/test_fuzz.py)
    raw = _raw("navigation")
    raw["planner"].setdefault("mppi", {})[key] = [10**400, 10**400]
    _refused(raw, rf"s.yaml: planner.mppi.{key}")
