"""The planner's command-line options, shared by ``m3p2i-planner`` and ``m3p2i``'s commands
(declared once here, as ``Annotated`` types; a command sets only the default). Light to import
(typer, no torch): ``m3p2i`` reads it too."""

from __future__ import annotations

from typing import Annotated

import typer

MeasureDelays = Annotated[
    bool,
    typer.Option(
        "--measure-delays",
        help="The planner measures the robot's delays online "
        "(planner.delays.measure): the state delay from the lag the world reports, the actuation "
        "delay from how the robot answers the controls sent; declared delays stand until then "
        "(docs/faults.md).",
    ),
]
OldMeasureDelays = Annotated[bool, typer.Option("--estimate-delays", hidden=True)]  # deprecated
Plugins = Annotated[
    list[str] | None,
    typer.Option(
        "--plugins",
        help="A Python module of your own cost terms for the planner to import (repeatable): "
        "a .py file or an importable module name, besides the scenario's plugins: "
        "(docs/cost_terms.md). Only the planner imports it.",
    ),
]
