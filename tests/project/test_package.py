"""m3p2i as an installed package: where scenario, objective and bench files are looked up (a path;
the folders of M3P2I_SCENARIOS; ./configs/scenarios; the shipped ones), ``m3p2i list`` and
``m3p2i new``; and, slow, a wheel built from the sources, installed into a fresh venv and run
from an empty folder."""

from __future__ import annotations

import os
import shutil
import site
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest
import yaml
from typer.testing import CliRunner

from m3p2i.bench import load_bench
from m3p2i.cli import app
from shared.config import ConfigError
from shared.config_files import ENV_VAR, find, shipped
from shared.scenario import SCENARIO_DIR, find_objectives, load_scenario

ROOT = Path(__file__).resolve().parents[2]
SHIPPED_NAMES = sorted(p.stem for p in SCENARIO_DIR.glob("*.yaml"))
BENCH_DIR = ROOT / "configs" / "bench"


@pytest.fixture
def user(tmp_path, monkeypatch):
    """An empty current folder, outside the repository, with M3P2I_SCENARIOS unset."""
    monkeypatch.chdir(tmp_path)
    monkeypatch.delenv(ENV_VAR, raising=False)
    return tmp_path


def write_scenario(folder: Path, name: str, description: str, base: str = "navigation") -> Path:
    """A copy of shipped scenario ``base`` as ``folder/NAME.yaml`` with its own description."""
    raw = yaml.safe_load((SCENARIO_DIR / f"{base}.yaml").read_text())
    raw.update(name=name, description=description)
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"{name}.yaml"
    path.write_text(yaml.safe_dump(raw))
    return path


def cli(*args: str):
    return CliRunner().invoke(app, list(args))


# ------------------------------------------------------------------------------------- lookup


def test_lookup_order_path_then_env_folders_then_current_folder_then_shipped(user, monkeypatch):
    first, second = user / "first", user / "second"
    monkeypatch.setenv(ENV_VAR, os.pathsep.join([str(first), str(second)]))
    local = user / "configs" / "scenarios"
    in_first = write_scenario(first, "a", "first")
    write_scenario(second, "a", "second")
    in_second = write_scenario(second, "b", "second")
    write_scenario(local, "b", "local")
    in_local = write_scenario(local, "c", "local")
    elsewhere = write_scenario(user / "elsewhere", "a", "a path")
    assert find("a") == in_first
    assert find("b") == in_second
    assert find("c") == in_local
    assert find("navigation") == SCENARIO_DIR / "navigation.yaml"
    assert find(elsewhere) == elsewhere  # a path is taken as given
    assert load_scenario("a").description == "first"


def test_a_users_file_shadows_the_shipped_one_and_list_says_so(user):
    mine = write_scenario(user / "configs" / "scenarios", "navigation", "my navigation")
    assert find("navigation") == mine
    assert load_scenario("navigation").description == "my navigation"
    out = cli("list")
    assert out.exit_code == 0, out.output
    lines = out.output.splitlines()
    assert lines[0] == "./configs/scenarios (current folder):"
    assert lines[1].split() == [
        "navigation",
        "[shadows",
        "the",
        "shipped",
        "navigation]",
        "my",
        "navigation",
    ]
    assert lines[2].startswith("shipped ") and lines[2].endswith("scenarios:")
    shipped_nav = next(line for line in lines[3:] if line.split()[0] == "navigation")
    assert "[not used: ./configs/scenarios/navigation.yaml comes first]" in shipped_nav
    assert sorted(line.split()[0] for line in lines[3:]) == SHIPPED_NAMES


def test_list_names_the_env_folders_and_a_missing_one(user, monkeypatch):
    mine = user / "mine"
    write_scenario(mine, "walk", "a walk")
    monkeypatch.setenv(ENV_VAR, os.pathsep.join([str(mine), str(user / "typo")]))
    out = cli("list").output.splitlines()
    assert out[0] == f"./mine ({ENV_VAR}):" and out[1].split() == ["walk", "a", "walk"]
    assert out[2] == f"./typo ({ENV_VAR}): not a folder"


def test_in_the_repository_its_configs_count_once_as_shipped(monkeypatch):
    monkeypatch.chdir(ROOT)
    monkeypatch.delenv(ENV_VAR, raising=False)
    out = cli("list").output
    assert "current folder" not in out and "shadows" not in out and "not used" not in out


def test_an_unknown_name_lists_the_names_and_the_folders_searched(user, monkeypatch):
    monkeypatch.setenv(ENV_VAR, str(user / "mine"))
    write_scenario(user / "configs" / "scenarios", "walk", "a walk")
    with pytest.raises(ConfigError) as err:
        find("navigaton")
    msg = str(err.value)
    assert msg.startswith("navigaton: no such scenario file or name")
    assert "one of: battery_enough, " in msg and ", walk; looked in: " in msg
    assert f"./mine ({ENV_VAR}); ./configs/scenarios (current folder); shipped " in msg
    out = cli("run", "navigaton")
    assert out.exit_code == 2 and "looked in:" in out.output


def test_objective_files_are_looked_up_beside_the_users_scenario_folders(user, monkeypatch):
    # the user's configs/objectives/push_pull.yaml replaces the shipped one for every scenario
    # that includes it, the shipped push as much as the user's own
    local = user / "configs" / "objectives"
    local.mkdir(parents=True)
    shutil.copy(shipped("objectives", "push_pull.yaml"), local)
    assert find_objectives("push_pull") == local / "push_pull.yaml"
    terms = load_scenario("push").objectives["push"].terms
    assert {t.source for t in terms} == {str(local / "push_pull.yaml")}
    # beside an M3P2I_SCENARIOS folder: <folder>/../objectives
    project = user / "project"
    write_scenario(project / "scenarios", "walk", "a walk")
    (project / "objectives").mkdir()
    (project / "objectives" / "walking.yaml").write_text("objectives: {}\n")
    monkeypatch.setenv(ENV_VAR, str(project / "scenarios"))
    assert find_objectives("walking") == project / "objectives" / "walking.yaml"
    assert find_objectives("push_pull") == local / "push_pull.yaml"


def test_bench_files_are_looked_up_like_scenarios(user):
    local = user / "configs" / "bench"
    local.mkdir(parents=True)
    (local / "mine.yaml").write_text(
        yaml.safe_dump({"cases": [{"case": "nav", "scenario": "navigation", "trials": 1}]})
    )
    assert load_bench("mine").source == str(local / "mine.yaml")
    assert Path(load_bench("paper").source) == shipped("bench", "paper.yaml")
    out = cli("list", "bench").output.splitlines()
    assert out[:2] == ["./configs/bench (current folder):", "  mine"]
    with pytest.raises(
        ConfigError,
        match=r"no such bench file or name .*one of: "
        + ", ".join(sorted(["mine", *(p.stem for p in BENCH_DIR.glob("*.yaml"))]))
        + ";",
    ):
        load_bench("nope")


# ---------------------------------------------------------------------------------- m3p2i new


def test_new_writes_a_renamed_copy_into_the_users_folder(user):
    out = cli("new", "mine", "--from", "navigation")
    assert out.exit_code == 0, out.output
    path = user / "configs" / "scenarios" / "mine.yaml"
    assert out.output.startswith("wrote ./configs/scenarios/mine.yaml, a copy of ")
    text = path.read_text()
    assert text.startswith("# Started from ") and "navigation.yaml by `m3p2i new`" in text
    sc = load_scenario("mine")
    assert sc.name == "mine" and Path(sc.source) == path
    assert sc.description == load_scenario("navigation").description


def test_new_goes_to_the_first_env_folder_and_may_shadow_a_shipped_name(user, monkeypatch):
    monkeypatch.setenv(ENV_VAR, str(user / "mine"))
    out = cli("new", "push", "--from", "push")  # include: [push_pull] still found
    assert out.exit_code == 0, out.output
    assert "it shadows " in out.output and "push.yaml (shipped)" in out.output
    assert load_scenario("push").source == str(user / "mine" / "push.yaml")


def test_new_refuses_to_overwrite(user):
    assert cli("new", "mine", "--from", "navigation").exit_code == 0
    path = user / "configs" / "scenarios" / "mine.yaml"
    path.write_text("# edited\n" + path.read_text())
    out = cli("new", "mine", "--from", "push")
    assert out.exit_code == 2
    assert (
        "./configs/scenarios/mine.yaml: exists already (m3p2i new never overwrites)" in out.output
    )
    assert path.read_text().startswith("# edited\n")


def test_new_from_an_unknown_scenario_or_with_a_path_as_name_fails_clearly(user):
    out = cli("new", "mine", "--from", "navigaton")
    assert out.exit_code == 2
    assert "navigaton: no such scenario file or name" in out.output and "navigation, " in out.output
    out = cli("new", "../mine", "--from", "navigation")
    assert out.exit_code == 2 and "../mine: not a scenario name" in out.output
    assert not (user / "configs").exists()


# ------------------------------------------------------------------------------------ the wheel


def test_pyproject_lists_every_package():
    """packages.find cannot see configs/ mapped to shared.configs, so the list is written out:
    a package missing from it would be missing from the wheel."""
    tomllib = pytest.importorskip("tomllib")  # Python 3.11+
    tool = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
    found = {
        ".".join(p.parent.relative_to(ROOT).parts)
        for top in ("m3p2i", "shared", "server", "planner_client")
        for p in (ROOT / top).rglob("__init__.py")
    }
    assert sorted(tool["packages"]) == sorted(found | {"shared.configs"})
    assert tool["package-dir"] == {"shared.configs": "configs"}


WHEEL_SOURCES = (
    "pyproject.toml",
    "README.md",
    "configs",
    "m3p2i",
    "shared",
    "server",
    "planner_client",
)


def run(cmd: list, cwd: Path, env: dict, timeout: float = 600) -> str:
    """Run ``cmd``; its output, or a failure that shows it."""
    done = subprocess.run(
        [str(c) for c in cmd], cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout
    )
    assert done.returncode == 0, f"{cmd} exited {done.returncode}:\n{done.stdout}\n{done.stderr}"
    return done.stdout


@pytest.mark.slow
def test_the_wheel_installs_and_runs_from_an_empty_folder(tmp_path):
    # the sources alone, so that no build/ left in the clone can slip into the wheel
    src = tmp_path / "src"
    src.mkdir()
    for name in WHEEL_SOURCES:
        if (ROOT / name).is_dir():
            shutil.copytree(ROOT / name, src / name, ignore=shutil.ignore_patterns("__pycache__"))
        else:
            shutil.copy(ROOT / name, src / name)
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", ENV_VAR)}
    run(
        [
            sys.executable,
            "-m",
            "pip",
            "wheel",
            "--no-deps",
            "--no-build-isolation",
            "--no-index",
            "-w",
            tmp_path / "dist",
            src,
        ],
        tmp_path,
        env,
    )
    (wheel,) = (tmp_path / "dist").glob("m3p2i-*.whl")
    carried = set(zipfile.ZipFile(wheel).namelist())
    configs = {
        f"shared/configs/{p.relative_to(ROOT / 'configs').as_posix()}"
        for p in (ROOT / "configs").rglob("*.yaml")
    }
    robots = {
        f"shared/robots/{p.name}"
        for p in (ROOT / "shared" / "robots").iterdir()
        if p.suffix in (".xml", ".yaml")
    }
    assert configs | robots <= carried

    # a fresh venv with the wheel alone; the test environment's packages (torch, mujoco, ...)
    # reused through a .pth file after its own site-packages, instead of installed again
    venv = tmp_path / "venv"
    run([sys.executable, "-m", "venv", "--without-pip", venv], tmp_path, env)
    python = venv / "bin" / "python"
    run(
        [
            sys.executable,
            "-m",
            "pip",
            "--python",
            python,
            "install",
            "--no-deps",
            "--no-index",
            wheel,
        ],
        tmp_path,
        env,
    )
    purelib = Path(
        run(
            [python, "-c", "import sysconfig; print(sysconfig.get_path('purelib'))"], tmp_path, env
        ).strip()
    )
    (purelib / "test-environment.pth").write_text("\n".join(site.getsitepackages()) + "\n")

    empty = tmp_path / "empty"
    empty.mkdir()
    m3p2i = venv / "bin" / "m3p2i"
    listed = run([m3p2i, "list"], empty, env).splitlines()
    assert listed[0] == f"shipped {purelib / 'shared' / 'configs' / 'scenarios'}:"
    assert sorted(line.split()[0] for line in listed[1:]) == SHIPPED_NAMES
    out = run([m3p2i, "run", "navigation", "--timeout", "500"], empty, env)
    assert "navigation: success" in out
    run([m3p2i, "new", "mine", "--from", "navigation"], empty, env)
    out = run([m3p2i, "run", "mine", "--timeout", "500"], empty, env)
    assert "mine: success" in out
    assert sorted(p.name for p in empty.iterdir()) == ["configs", "runs"]
