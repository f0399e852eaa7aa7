"""Simulated faults (server/faults.py, shared/scenario/faults.py, docs/faults.md): each fault
happens as configured, the profiles load, bad values are refused clearly, ``--faults`` reaches the
world's command line and not the planner's, and the old names (``hardware:``, ``--hardware``)
still mean the same."""

from __future__ import annotations

import dataclasses
import math

import mujoco
import numpy as np
import pytest
import typer
import yaml
from typer.testing import CliRunner

import shared.config
from m3p2i.bench import load_bench
from m3p2i.cli import app as m3p2i
from m3p2i.launch import EpisodeLaunch
from planner_client.problem import build_problem
from server.cli import app as server_cli
from server.evaluation import log_reader
from server.faults import FaultyWorld
from server.options import load_faults
from server.world import SimWorld
from shared.config import ConfigError, load_yaml
from shared.scenario import find_scenario, load_scenario, parse_scenario
from shared.scenario.faults import (
    NOMINAL,
    PROFILES,
    FaultConfig,
    MismatchConfig,
    steps_of,
)


@pytest.fixture(scope="module")
def push():
    return load_scenario("push")  # point robot (velocity control) and a free box, dt 0.05


def u(x: float, y: float = 0.0) -> np.ndarray:
    """A point_robot_suction control: velocities x, y; suction off."""
    return np.array([x, y, 0.0])


def faulty(sc, seed: int = 0, **faults) -> FaultyWorld:
    return FaultyWorld(SimWorld(sc, seed), FaultConfig(**faults))


# ---------------------------------------------------------------- configuration


def test_profiles_hold_the_issues_numbers():
    assert not PROFILES["nominal"].active and NOMINAL == FaultConfig()
    lab = PROFILES["lab"]
    assert lab.actuation_delay_ms + lab.state_delay_ms >= 50  # round trip
    assert lab.position_noise_m == 0.005 and lab.drop_rate == 0.10
    assert lab.mismatch.mass == 0.3 and lab.mismatch.friction == 0.3
    harsh = PROFILES["harsh"]
    for f in ("actuation_delay_ms", "state_delay_ms", "position_noise_m", "drop_rate"):
        assert getattr(harsh, f) > getattr(lab, f), f
    assert load_faults("lab") is lab


def test_a_file_or_a_section_overrides_a_profile(tmp_path):
    f = tmp_path / "faults.yaml"
    f.write_text("faults: {profile: lab, drop_rate: 0.2, mismatch: {gain: 0}}\n")
    faults = load_faults(str(f))
    assert faults == dataclasses.replace(
        PROFILES["lab"], drop_rate=0.2, mismatch=MismatchConfig(mass=0.3, friction=0.3, gain=0.0)
    )
    f.write_text("state_delay_ms: 40\n")  # the keys at the top level
    assert load_faults(str(f)) == FaultConfig(state_delay_ms=40.0)
    raw = load_yaml(find_scenario("push"))
    assert parse_scenario({**raw, "faults": "harsh"}, "push.yaml").faults is PROFILES["harsh"]
    assert load_scenario("push").faults == NOMINAL


@pytest.mark.parametrize(
    "value, key, expected",
    [
        ({"drop_rate": 1.5}, "faults.drop_rate", "[0, 1)"),
        ({"state_delay_ms": -5}, "faults.state_delay_ms", "milliseconds"),
        ({"gripper": "sticky"}, "faults.gripper", "continuous or binary"),
        ({"hide_velocities": "yes"}, "faults.hide_velocities", "true or false"),
        ({"mismatch": {"mass": 2}}, "faults.mismatch.mass", "±30 %"),
        ({"noise": 0.1}, "faults.noise", "position_noise_m"),
        ("lab2", "faults", "nominal, lab, harsh"),
        ({"profile": "lab2"}, "faults.profile", "nominal, lab, harsh"),
    ],
)
def test_bad_values_name_file_key_value_and_what_was_expected(value, key, expected):
    raw = load_yaml(find_scenario("push"))
    with pytest.raises(ConfigError) as err:
        parse_scenario({**raw, "faults": value}, "my.yaml")
    text = str(err.value)
    assert "my.yaml" in text and key in text and expected in text, text


def test_an_unknown_profile_or_file_is_refused():
    with pytest.raises(ConfigError, match=r"neither a profile nor a file.*nominal, lab, harsh"):
        load_faults("no_such_profile")


def test_the_old_names_hardware_and_dash_dash_hardware_mean_faults(tmp_path, monkeypatch):
    # hardware: and --hardware, the names before faults: and --faults, read the same and warn
    # once (per file), naming the new spelling
    monkeypatch.setattr(shared.config, "_WARNED", set())
    raw = load_yaml(find_scenario("push"))
    spec = {"profile": "lab", "drop_rate": 0.2}
    new = parse_scenario({**raw, "faults": spec}, "push.yaml")
    with pytest.warns(FutureWarning, match=r"hardware: \(in push.yaml\) is deprecated.*faults:"):
        old = parse_scenario({**raw, "hardware": spec}, "push.yaml")
    assert old.faults == new.faults == dataclasses.replace(PROFILES["lab"], drop_rate=0.2)
    # one hash for both names (bench results, logs and peers keep matching), not the nominal's
    assert old.hash == new.hash != parse_scenario(raw, "push.yaml").hash
    # over a base: each file's old name is read as the new one before they merge
    (tmp_path / "base.yaml").write_text("base: push\nname: base\nhardware: {profile: lab}\n")
    (tmp_path / "mine.yaml").write_text("base: base.yaml\nname: mine\nfaults: {drop_rate: 0.3}\n")
    with pytest.warns(FutureWarning, match=r"hardware: \(in .*base.yaml\)"):
        mine = load_scenario(tmp_path / "mine.yaml")
    assert mine.faults == dataclasses.replace(PROFILES["lab"], drop_rate=0.3)
    f = tmp_path / "old.yaml"
    f.write_text("hardware: harsh\n")  # a faults file under the old key
    with pytest.warns(FutureWarning, match=r"hardware: \(in .*old.yaml\)"):
        assert load_faults(str(f)) is PROFILES["harsh"]
    # a bench case's hardware:
    bench = tmp_path / "bench.yaml"
    case = {"case": "a", "scenario": "navigation", "trials": 1, "compensate": True}
    bench.write_text(yaml.safe_dump({"cases": [{**case, "faults": "lab"}]}))
    cases = [load_bench(bench).cases[0]]
    bench.write_text(yaml.safe_dump({"cases": [{**case, "hardware": "lab"}]}))
    with pytest.warns(FutureWarning, match=r"hardware: \(in .*bench.yaml\)"):
        cases.append(load_bench(bench).cases[0])
    assert cases[0] == cases[1] and cases[0].faults == "lab" and cases[0].delays == (25.0, 25.0)
    assert cases[0].mode_label == "lockstep, faults lab, compensated"
    # --hardware: a second name of the same option, on m3p2i-server and m3p2i run
    server = typer.main.get_command(server_cli)
    run = typer.main.get_command(m3p2i).commands["run"]
    for flag, param in (("--faults", "faults"), ("--hardware", "hardware")):
        ctx = server.make_context("m3p2i-server", ["-s", "push", flag, "lab"])
        assert ctx.params[param] == "lab", flag
        assert run.make_context("run", ["push", flag, "lab"]).params[param] == "lab", flag
    with pytest.warns(FutureWarning, match="--hardware is deprecated.*write --faults"):
        result = CliRunner().invoke(
            server_cli, ["--scenario", "push", "--check", "--hardware", "x"]
        )
    assert result.exit_code == 2 and "--faults: neither a profile nor a file" in result.output
    result = CliRunner().invoke(server_cli, ["-s", "push", "--faults", "lab", "--hardware", "lab"])
    assert result.exit_code == 2 and "both --faults and --hardware" in result.output


def test_a_log_written_before_the_rename_still_tells_its_faults():
    old = [
        {
            "kind": "header",
            "hardware": {"drop_rate": 0.1},
            "hardware_mismatch": {"mass": {}},
            "hardware_delays": {"actuation": 1},
        }
    ]
    assert log_reader.faults(old) == {
        "faults": {"drop_rate": 0.1},
        "faults_mismatch": {"mass": {}},
        "faults_delays": {"actuation": 1},
    }
    assert log_reader.faults([{"kind": "header"}]) == {}


def test_both_names_at_once_are_an_error_naming_the_file_and_both_keys(tmp_path):
    raw = load_yaml(find_scenario("push"))
    with pytest.raises(ConfigError) as err:
        parse_scenario({**raw, "faults": "lab", "hardware": "harsh"}, "my.yaml")
    assert (
        "my.yaml" in str(err.value)
        and "faults:" in str(err.value)
        and "hardware:" in str(err.value)
    ), err.value
    (tmp_path / "mine.yaml").write_text("base: push\nname: mine\nfaults: lab\nhardware: lab\n")
    with pytest.raises(ConfigError, match=r"mine\.yaml: hardware: both faults: and hardware:"):
        load_scenario(tmp_path / "mine.yaml")
    f = tmp_path / "both.yaml"
    f.write_text("faults: lab\nhardware: lab\n")
    with pytest.raises(ConfigError, match=r"both\.yaml: hardware: both faults: and hardware:"):
        load_faults(str(f))
    bench = tmp_path / "bench.yaml"
    bench.write_text(
        yaml.safe_dump(
            {
                "cases": [
                    {
                        "case": "a",
                        "scenario": "navigation",
                        "trials": 1,
                        "faults": "lab",
                        "hardware": "lab",
                    }
                ]
            }
        )
    )
    with pytest.raises(ConfigError, match="both faults: and hardware:") as err:
        load_bench(bench)
    assert err.value.source == str(bench) and err.value.path == "cases[0].hardware"


# ---------------------------------------------------------------- the faults


def test_a_delayed_command_takes_effect_after_the_delay_in_world_steps(push):
    world = faulty(push, actuation_delay_ms=150.0)  # 3 steps of 0.05 s
    assert steps_of(150.0, world.dt) == 3
    go = u(0.5, -0.25)
    applied = []
    for i in range(6):
        world.step(go if i == 0 else u(0.0))
        applied.append(world.ctrl.copy())
    assert [bool(np.allclose(a, go)) for a in applied] == [False, False, False, True, False, False]
    assert np.allclose(applied[0], world.robot.safe_stop())


def test_a_realtime_delay_is_wall_clock(push):
    clock = [0.0]
    world = FaultyWorld(
        SimWorld(push), FaultConfig(actuation_delay_ms=50.0), realtime=True, clock=lambda: clock[0]
    )
    go = u(0.5)
    applied = []
    for _ in range(5):  # a step every 20 ms: the command arrives at 60 ms
        world.step(go)
        applied.append(float(world.ctrl[0]))
        clock[0] += 0.02
    assert applied == [0.0, 0.0, 0.0, 0.5, 0.5]


@pytest.mark.parametrize("factor", [1.0, 0.5, 2.0])
def test_realtime_delays_are_the_declared_world_steps_at_any_realtime_factor(
    push, tmp_path, factor
):
    # --compensate declares the delays as world steps (steps_of); the world at
    # --realtime-factor 0.5 steps every dt / 0.5 wall seconds: its delays must count world
    # seconds too, or a 120 ms delay (3 steps declared at dt 0.05) acts after 2
    from m3p2i.launch import free_port_block
    from server.app import ServerOptions, WorldServer
    from shared.endpoints import Endpoints

    ms = 120.0
    server = WorldServer(
        push,
        Endpoints(port=free_port_block()),
        tmp_path / "log.jsonl",
        options=ServerOptions(mode="realtime", realtime_factor=factor),
        faults=FaultConfig(actuation_delay_ms=ms, state_delay_ms=ms),
    )
    try:
        world = server.world
        wall = [1000.0]
        world._clock = lambda: wall[0]  # the monotonic clock, stepped as real time does
        world.reset()
        declared = steps_of(ms, world.dt)
        assert declared == 3
        go, applied, seen = u(0.5), None, None
        for k in range(1, 10):
            world.step(go if k == 1 else u(0.0))  # sent at step 1
            if applied is None and np.allclose(world.ctrl, go):
                applied = k - 1  # world steps the command waited
            if seen is None and world.state().time > 0:  # published as the step is taken
                seen = k - 1  # world steps since step 1's measurement
            wall[0] += world.dt / factor
        assert applied == declared
        assert seen == declared
    finally:
        server.close()


def test_a_delayed_state_was_measured_the_delay_ago(push):
    world = faulty(push, state_delay_ms=100.0)  # 2 steps
    for _ in range(5):
        world.step(u(0.4))
        assert world.state().time == pytest.approx(max(0.0, world.time - 0.1))
    assert world.true_state().time == pytest.approx(world.time)
    assert world.state().qpos[0] < world.true_state().qpos[0]  # it has moved on since


def test_an_object_moved_by_a_control_op_is_seen_after_the_state_delay(push):
    world = faulty(push, state_delay_ms=50.0)  # 1 step
    box = world.model.joint("box_free").qposadr[0]
    world.move_object("box", [2.0, -1.0, 0.05])
    assert world.state().qpos[box] != 2.0
    world.step(u(0.0))
    assert world.state().qpos[box] == pytest.approx(2.0)


def test_the_control_period_holds_each_command_k_steps(push):
    world = faulty(push, control_period_ms=150.0)  # every 3rd step
    applied = []
    for i in range(7):
        world.step(u(0.1 * (i + 1)))
        applied.append(round(float(world.ctrl[0]), 6))
    assert applied == [0.1, 0.1, 0.1, 0.4, 0.4, 0.4, 0.7]


def test_noise_has_the_configured_spread_and_quaternions_stay_unit(push):
    world = faulty(push, position_noise_m=0.005, angle_noise_rad=0.02)
    truth = world.true_state()
    box = world.model.joint("box_free").qposadr[0]
    samples = [world.measure(truth) for _ in range(2000)]
    err = np.array([s.qpos[box : box + 3] - truth.qpos[box : box + 3] for s in samples]).ravel()
    robot = np.array([s.qpos[:2] - truth.qpos[:2] for s in samples]).ravel()
    # 6000 and 4000 draws: the sample σ is within 3 % of σ with overwhelming probability
    assert np.std(err) == pytest.approx(0.005, rel=0.05) and abs(np.mean(err)) < 0.0005
    assert np.std(robot) == pytest.approx(0.005, rel=0.05)
    quats = np.array([s.qpos[box + 3 : box + 7] for s in samples])
    assert np.allclose(np.linalg.norm(quats, axis=1), 1.0)
    q0 = truth.qpos[box + 3 : box + 7]
    angles = 2 * np.arccos(np.clip(np.abs(quats @ q0), 0, 1))
    # the angle of a rotation vector with σ per axis: its RMS is √3 σ
    assert math.sqrt(np.mean(angles**2)) == pytest.approx(math.sqrt(3) * 0.02, rel=0.06)


def test_joint_noise_is_on_the_arms_hinges_and_a_fingers_slide_is_exact():
    world = FaultyWorld(
        SimWorld(load_scenario("pick_place")),
        FaultConfig(joint_noise_rad=0.001, position_noise_m=0.005),
    )
    truth = world.true_state()
    hinges = world.model.jnt_qposadr[world.model.jnt_type == mujoco.mjtJoint.mjJNT_HINGE]
    samples = np.array([world.measure(truth).qpos - truth.qpos for _ in range(500)])
    assert np.std(samples[:, hinges]) == pytest.approx(0.001, rel=0.06)
    fingers = world.model.jnt_qposadr[world.model.jnt_type == mujoco.mjtJoint.mjJNT_SLIDE]
    assert len(fingers) == 2 and np.all(samples[:, fingers] == 0)  # encoders: exact
    cube = world.model.joint("cube_a_free").qposadr[0]
    assert np.std(samples[:, cube : cube + 3]) == pytest.approx(0.005, rel=0.1)  # the tracker's


def test_object_velocities_are_withheld_and_the_robots_kept(push):
    world = faulty(push, hide_velocities=True)
    s = world.inner.state()
    s.qvel[:] = 1.0
    m = world.measure(s)
    box = world.model.joint("box_free").dofadr[0]
    assert np.all(m.qvel[box : box + 6] == 0) and np.all(m.qvel[:2] == 1.0)


def test_states_are_dropped_at_the_configured_rate(push):
    world = faulty(push, drop_rate=0.1)
    n = 10000
    dropped = sum(world.drop_state() for _ in range(n))
    # binomial: σ = √(p (1 - p) / n) = 0.003; 4 σ
    assert abs(dropped / n - 0.1) < 4 * math.sqrt(0.1 * 0.9 / n)
    assert not any(faulty(push).drop_state() for _ in range(100))


def test_a_binary_gripper_only_opens_or_closes():
    sc = load_scenario("pick_place")
    world = FaultyWorld(SimWorld(sc), FaultConfig(gripper="binary"))
    g = world.robot.ctrl_names.index("gripper")
    lo, hi = world.model.actuator_ctrlrange[g]
    for command, expected in ((0.05, hi), (0.03, lo), (hi, hi), (0.0, lo)):
        ctrl = np.zeros(world.model.nu)
        ctrl[g] = command
        world.step(ctrl)
        assert world.ctrl[g] == expected


def test_mismatch_reaches_the_world_and_not_the_planner(push):
    hw = FaultConfig(mismatch=MismatchConfig(mass=0.3, friction=0.3, gain=0.2))
    nominal = SimWorld(push).model
    world = FaultyWorld(SimWorld(push, seed=7), hw)
    planner = build_problem(push).model
    box = nominal.body("box").id
    f = world.mismatch
    assert 0.7 <= f["mass"]["box"] <= 1.3 and f["mass"]["box"] != 1.0
    assert world.model.body_mass[box] == pytest.approx(nominal.body_mass[box] * f["mass"]["box"])
    geom = nominal.geom("box").id
    assert world.model.geom_friction[geom, 0] == pytest.approx(
        nominal.geom_friction[geom, 0] * f["friction"]["box"]
    )
    gains = np.array(list(f["gain"].values()))
    assert world.model.actuator_gainprm[:, 0] == pytest.approx(
        nominal.actuator_gainprm[:, 0] * gains
    )
    # the planner's model is built from the YAML: the nominal numbers
    assert planner.body_mass[planner.body("box").id] == nominal.body_mass[box]
    assert planner.geom_friction[planner.geom("box").id, 0] == nominal.geom_friction[geom, 0]
    assert np.array_equal(planner.actuator_gainprm, nominal.actuator_gainprm)
    # drawn from the seed: the same seed the same factors, another seed others
    assert FaultyWorld(SimWorld(push, seed=7), hw).mismatch == f
    assert FaultyWorld(SimWorld(push, seed=8), hw).mismatch != f


def test_a_faulty_episode_repeats_exactly_from_its_seed(push):
    def run(seed):
        world = FaultyWorld(SimWorld(push, seed), PROFILES["harsh"])
        rng = np.random.default_rng(0)
        out = []
        for _ in range(40):
            world.step(u(*rng.uniform(-1, 1, 2)))
            s = world.state()
            out.append(np.concatenate([s.qpos, s.qvel, world.true_state().qpos]))
        return np.array(out), [world.drop_state() for _ in range(50)]

    (a, drops_a), (b, drops_b), (c, _) = run(3), run(3), run(4)
    assert np.array_equal(a, b) and drops_a == drops_b
    assert not np.array_equal(a, c)


def test_the_server_wraps_its_world_only_for_faults_and_logs_truth_and_faults(push, tmp_path):
    from m3p2i.launch import free_port_block
    from server.app import WorldServer
    from server.episode_log import read_log
    from shared.endpoints import Endpoints

    server = WorldServer(
        push, Endpoints(port=free_port_block()), tmp_path / "a.jsonl", faults=PROFILES["nominal"]
    )
    assert type(server.world) is SimWorld  # nominal: the simulation itself, bit for bit
    server.close()
    server = WorldServer(
        push,
        Endpoints(port=free_port_block()),
        tmp_path / "b.jsonl",
        seed=5,
        faults=dataclasses.replace(PROFILES["lab"], drop_rate=0.5),
    )
    try:
        assert isinstance(server.world, FaultyWorld)
        for _ in range(3):
            server.step(u(0.5, 0.2))
        # a state is lost at most once: re-publishing the same seq always sends it
        before = server.episode.dropped
        for _ in range(5):
            server.publish()
        assert server.episode.dropped == before
        n = 400
        for _ in range(n):
            server.episode.seq += 1
            server.publish()
        assert abs((server.episode.dropped - before) / n - 0.5) < 4 * math.sqrt(0.25 / n)
        server.log.close()
        records = read_log(tmp_path / "b.jsonl")
        header = records[0]
        assert header["faults"]["drop_rate"] == 0.5 and "box" in header["faults_mismatch"]["mass"]
        # lab's 25 ms each way at 50 ms steps: one step each (rounded up)
        assert header["faults_delays"] == {
            "actuation": 1,
            "state": 1,
            "unit": "steps",
            "control_period_steps": 1,
        }
        assert log_reader.faults(records) == {
            k: header[k] for k in ("faults", "faults_mismatch", "faults_delays")
        }
        step = [r for r in records if r.get("kind", r.get("type")) == "step"][-1]
        assert np.allclose(step["qpos"], server.world.true_state().qpos)  # the log: the truth
        assert not np.allclose(step["qpos"], server.world.state().qpos)  # the planner: noise
    finally:
        server.close()


# ---------------------------------------------------------------- the command lines


def test_the_flag_reaches_the_worlds_command_line_only(tmp_path):
    cmds = EpisodeLaunch(scenario="push.yaml", run_dir=tmp_path, faults="lab").commands(5555)
    server = cmds["server"]
    assert server[server.index("--faults") + 1] == "lab"
    assert "--faults" not in cmds["planner"]
    assert (
        "--faults"
        not in EpisodeLaunch(scenario="push.yaml", run_dir=tmp_path).commands(5555)["server"]
    )


def test_a_bad_flag_stops_both_commands_before_anything_starts(tmp_path):
    result = CliRunner().invoke(
        m3p2i, ["run", "push", "--faults", "lab2", "--run-dir", str(tmp_path)]
    )
    assert result.exit_code == 2 and "neither a profile nor a file" in result.output
    assert not any(tmp_path.iterdir())
    result = CliRunner().invoke(server_cli, ["--scenario", "push", "--check", "--faults", "lab2"])
    assert result.exit_code == 2 and "lab2" in result.output
    result = CliRunner().invoke(server_cli, ["--scenario", "push", "--check", "--faults", "harsh"])
    assert result.exit_code == 0, result.output


def test_scaled_contact_friction_leaves_the_grippers_pads_in_charge_of_their_contacts():
    """``friction_of: contacts`` ranks the objects above the floor and the links so their
    scaled friction is their contacts', and below the Panda's rubber pads (priority 1, condim 4,
    stiff solimp): a pinched cube's contacts stay the pads', whatever its factor. Before, the
    cube outranked the pads, its pinch lost their torsional friction and stiffness, and every
    carried cube slipped out under ``mismatch``."""
    sc = load_scenario("pick_place")
    nominal = SimWorld(sc).model
    faults = FaultConfig(mismatch=MismatchConfig(friction=0.5, friction_of="contacts"))
    model = FaultyWorld(SimWorld(sc, seed=3), faults).model
    prio = model.geom_priority
    pads = np.flatnonzero(nominal.geom_priority > 0)
    objects = [nominal.body(n).id for n in ("table", "cube_a", "cube_b")]
    cubes = np.flatnonzero(np.isin(nominal.geom_bodyid, objects))
    rest = np.setdiff1d(np.arange(nominal.ngeom), np.concatenate([pads, cubes]))
    assert len(pads) == 2 and len(cubes) == 3
    assert prio[pads].min() > prio[cubes].max() >= prio[cubes].min() > prio[rest].max()
    # the objects' scaled friction applies against the floor and the links
    for name in ("table", "cube_a", "cube_b"):
        geom = model.geom(name).id
        f = FaultyWorld(SimWorld(sc, seed=3), faults).mismatch["friction"][name]
        assert model.geom_friction[geom, 0] == pytest.approx(
            max(nominal.geom_friction[geom, 0], nominal.geom_friction[rest, 0].max()) * f
        )
