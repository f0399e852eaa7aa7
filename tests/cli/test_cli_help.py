"""``--help`` of the three programs reads as flowing sentences; their shared options are one
declaration (shared.cli_common, or server.options and planner_client.options for one side's).

Typer's rich help rewraps an option's help and a command's first paragraph, but keeps the hard
line breaks of a command's later paragraphs: a docstring wrapped at 100 columns in the source
then breaks sentences in the middle on any terminal. Every help text is therefore paragraphs
without line breaks (``m3p2i.cli_support.flowing``), and rich markup must not eat any of it
(``m3p2i[view]`` is a markup tag unless escaped).
"""

from __future__ import annotations

import inspect
import warnings

import click
import pytest
import typer
from rich.text import Text
from typer.testing import CliRunner

import shared.config
from m3p2i.cli import app as m3p2i_app
from planner_client.cli import app as planner_app
from server.cli import app as server_app
from shared.cli_common import renamed

APPS = {"m3p2i": m3p2i_app, "m3p2i-server": server_app, "m3p2i-planner": planner_app}


def _commands() -> list[tuple[str, typer.Typer, list[str], click.Command]]:
    """(program, app, arguments before --help, click command) of every command."""
    out = []
    for prog, app in APPS.items():
        cmd = typer.main.get_command(app)
        out.append((prog, app, [], cmd))
        for name, sub in getattr(cmd, "commands", {}).items():
            out.append((prog, app, [name], sub))
    return out


COMMANDS = _commands()
IDS = [" ".join([prog, *args]) for prog, _, args, _ in COMMANDS]


def _paragraphs(text: str) -> list[str]:
    return [p for p in inspect.cleandoc(text).split("\n\n") if p.strip()]


def _plain(markup: str) -> str:
    """What rich shows of ``markup``, escapes removed."""
    return Text.from_markup(markup).plain


@pytest.mark.parametrize("prog, app, args, cmd", COMMANDS, ids=IDS)
def test_help_texts_are_paragraphs_without_line_breaks(prog, app, args, cmd):
    texts = {"(command)": cmd.help or ""}
    texts.update({p.name: getattr(p, "help", None) or "" for p in cmd.params})
    assert cmd.help, f"{prog} {' '.join(args)}: no help text"
    for name, text in texts.items():
        for paragraph in _paragraphs(text):
            assert "\n" not in paragraph, f"{prog} {' '.join(args)} {name}: {paragraph!r}"
            shown = _plain(paragraph)
            assert shown == paragraph.replace("\\[", "["), (
                f"{prog} {' '.join(args)} {name}: rich markup changed {paragraph!r} "
                f"into {shown!r} (escape '[' as '\\\\[')"
            )


@pytest.mark.parametrize("prog, app, args, cmd", COMMANDS, ids=IDS)
def test_help_renders_each_paragraph_on_one_line_of_a_wide_terminal(prog, app, args, cmd):
    result = CliRunner().invoke(
        app, [*args, "--help"], prog_name=prog, env={"COLUMNS": "3000", "TERMINAL_WIDTH": "3000"}
    )
    assert result.exit_code == 0, result.output
    lines = [" ".join(line.split()) for line in result.output.splitlines()]
    for paragraph in _paragraphs(cmd.help or ""):
        flat = " ".join(_plain(paragraph).split())
        assert flat in lines, f"{prog} {' '.join(args)}: {flat!r} not on one line"


def _params(app: typer.Typer, *args: str) -> dict[str, click.Parameter]:
    cmd = typer.main.get_command(app)
    for name in args:
        cmd = cmd.commands[name]
    return {p.name: p for p in cmd.params}


def test_shared_options_are_declared_once():
    # the same flags, help and type wherever the three programs share an option
    server, planner = _params(server_app), _params(planner_app)
    run, view = _params(m3p2i_app, "run"), _params(m3p2i_app, "view")
    for name, where in (
        ("host", (server, planner, view)),
        ("keys", (server, planner, run, view)),
        ("insecure", (server, planner)),
        ("verbose", (server, planner, run)),
        ("mode", (server, run)),
        ("faults", (server, run)),
        ("plan_every", (server, run)),
        ("window", (server, run)),
        ("measure_delays", (planner, run)),
    ):
        shown = {(tuple(p[name].opts), tuple(p[name].secondary_opts), p[name].help) for p in where}
        assert len(shown) == 1, (name, shown)
    assert server["scenario"].opts == planner["scenario"].opts == ["--scenario", "-s"]


def test_the_mujoco_window_keeps_its_old_name_with_a_warning(monkeypatch):
    # --window (MuJoCo's window) beside m3p2i run's --view (the browser page); --viewer, its
    # name before, still opens it, warns once naming --window, and is hidden from --help
    monkeypatch.setattr(shared.config, "_WARNED", set())
    server = typer.main.get_command(server_app)
    for args, shown in (([], False), (["--window"], True)):
        ctx = server.make_context("m3p2i-server", ["-s", "navigation", *args])
        assert ctx.params["window"] is shown, args
    assert server.make_context("m3p2i-server", ["-s", "navigation", "--viewer"]).params["viewer"]
    run = typer.main.get_command(m3p2i_app).commands["run"]
    assert run.make_context("run", ["navigation", "--viewer"]).params["viewer"] is True
    assert "--viewer" not in CliRunner().invoke(server_app, ["--help"]).output
    with pytest.warns(
        FutureWarning, match="--viewer is deprecated and will be removed: write --window"
    ):
        assert renamed(False, True, "--window", "--viewer", False) is True
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # once per process
        assert renamed(False, True, "--window", "--viewer", False) is True
        assert renamed(True, False, "--window", "--viewer", False) is True
    with pytest.raises(typer.BadParameter, match="both --window and --viewer"):
        renamed(True, True, "--window", "--viewer", False)
