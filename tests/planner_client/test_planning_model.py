"""``planner.model``: the planner's own copy of the model (solver, cone, integrator, contacts)
changes with it and the world's never does; every key is validated, naming file, key, value."""

import mujoco
import pytest
import yaml

from planner_client.planner_check import scenario_errors
from planner_client.problem import build_problem
from shared.config import ConfigError
from shared.scenario import SCENARIO_DIR, parse_scenario
from shared.scene import compile_model

MODEL = {
    "solver": "CG",
    "iterations": 7,
    "ls_iterations": 5,
    "tolerance": 1e-5,
    "cone": "elliptic",
    "noslip_iterations": 2,
    "integrator": "Euler",
    "condim": 1,
    "exclude": [["robot", "box"]],
}


def _push_pull(model: dict) -> dict:
    raw = yaml.safe_load((SCENARIO_DIR / "push_pull.yaml").read_text())
    raw["planner"]["model"] = model
    return raw


def test_the_planners_model_takes_the_options_and_the_world_keeps_its_own():
    sc = parse_scenario(_push_pull(MODEL), str(SCENARIO_DIR / "push_pull.yaml"))
    planner, world = build_problem(sc).model, compile_model(sc)
    opt = planner.opt
    assert (
        opt.solver,
        opt.iterations,
        opt.ls_iterations,
        opt.tolerance,
        opt.cone,
        opt.noslip_iterations,
        opt.integrator,
    ) == (
        mujoco.mjtSolver.mjSOL_CG,
        7,
        5,
        1e-5,
        mujoco.mjtCone.mjCONE_ELLIPTIC,
        2,
        mujoco.mjtIntegrator.mjINT_EULER,
    )
    assert set(planner.geom_condim) == {1} and planner.nexclude == 1
    robot, box = (mujoco.mj_name2id(planner, mujoco.mjtObj.mjOBJ_BODY, n) for n in ("robot", "box"))
    assert {planner.exclude_signature[0] >> 16, planner.exclude_signature[0] & 0xFFFF} == {
        robot,
        box,
    }
    # the world simulates the scenario's physics whatever the planner rolls out
    assert (world.opt.solver, world.opt.cone, world.opt.integrator, world.nexclude) == (
        mujoco.mjtSolver.mjSOL_NEWTON,
        mujoco.mjtCone.mjCONE_PYRAMIDAL,
        mujoco.mjtIntegrator.mjINT_IMPLICITFAST,
        0,
    )
    assert set(world.geom_condim) == {3}


@pytest.mark.parametrize(
    "key, value, expected",
    [
        ("solver", "cg", "one of: CG, Newton, PGS"),
        ("iterations", 0, "positive integer"),
        ("ls_iterations", 2.5, "positive integer"),
        ("tolerance", -1, ">= 0"),
        ("cone", "round", "one of: elliptic, pyramidal"),
        ("noslip_iterations", -1, "integer >= 0"),
        ("integrator", "rk4", "one of: Euler, RK4, implicit, implicitfast"),
        ("condim", 2, "1, 3, 4 or 6"),
        ("exclude", [["robot"]], "[body, body] pairs"),
        ("solvr", "CG", "unknown key"),
    ],
)
def test_each_key_is_checked_naming_file_key_and_value(key, value, expected):
    with pytest.raises(ConfigError) as info:
        parse_scenario(_push_pull({key: value}), "pp.yaml")
    msg = str(info.value)
    assert msg.startswith(f"pp.yaml: planner.model.{key}") and expected in msg, msg


def test_an_excluded_body_the_model_lacks_is_a_check_error(tmp_path):
    raw = _push_pull({"exclude": [["robot", "box"], ["robot", "crate"]]})
    raw["include"] = [str(SCENARIO_DIR.parent / "objectives" / "push_pull.yaml")]
    path = tmp_path / "pp.yaml"
    path.write_text(yaml.safe_dump(raw))
    errors = [str(e) for e in scenario_errors(path)]
    assert len(errors) == 1 and "planner.model.exclude[1]" in errors[0] and "'crate'" in errors[0]
