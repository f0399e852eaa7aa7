"""``m3p2i layout``'s tables: a scenario's :class:`~m3p2i.bridge_layout.BridgeLayout` for a person,
and the frame names its YAML may use (:func:`m3p2i.bridge_layout.frame_names`)."""

from __future__ import annotations

from rich.console import Console
from rich.table import Table

from m3p2i.bridge_layout import BridgeLayout, Coordinate, FrameName


def _vector(values) -> str:
    return "(" + ", ".join(f"{v:g}" for v in values) + ")" if values is not None else ""


def _coordinates(title: str, rows: tuple[Coordinate, ...], ranges: bool) -> Table:
    table = Table(title=title, title_justify="left")
    for column in ("index", "joint", "type", "body", "component", "unit", "frame", "axis"):
        table.add_column(column, justify="right" if column == "index" else "left")
    if ranges:
        table.add_column("range")
    for r in rows:
        cells = [
            str(r.index),
            r.joint,
            r.joint_type,
            r.body,
            r.component,
            r.unit,
            r.frame,
            _vector(r.axis),
        ]
        table.add_row(*cells, *([_vector(r.range)] if ranges else []))
    return table


def print_layout(layout: BridgeLayout, console: Console) -> None:
    """Every index of the state a world sends and the command it accepts, as tables."""
    s = layout.sizes
    console.print(
        f"[bold]{layout.scenario}[/]: robot {layout.robot}, world timestep "
        f"{layout.dt:g} s, scenario hash {layout.scenario_hash}"
    )
    console.print(
        f"state: qpos [{s.nq}], qvel [{s.nv}], act [{s.na}], mocap_pos "
        f"[{s.nmocap}, 3], mocap_quat [{s.nmocap}, 4]; command: ctrl [{layout.nu}] "
        f"(plan_ctrl [H, {layout.nu}])",
        highlight=False,
    )
    for r in layout.team:
        console.print(
            f"robot {r.name} (m3p2i-planner --robot {r.name}): command.ctrl "
            f"[{r.ctrl[1] - r.ctrl[0]}] = the world's ctrl[{r.ctrl[0]}:{r.ctrl[1]}]; "
            f"its joints qpos[{r.qpos[0]}:{r.qpos[1]}], qvel[{r.qvel[0]}:{r.qvel[1]}]",
            highlight=False,
        )
    console.print(_coordinates(f"state.qpos [{s.nq}]: positions", layout.qpos, ranges=True))
    console.print(_coordinates(f"state.qvel [{s.nv}]: velocities", layout.qvel, ranges=False))
    console.print(
        "frame: world = the world frame (a free joint: its body frame's origin and "
        "orientation, its linear velocity); body = the body's own frame (angular "
        "velocity, MuJoCo's convention); parent = rotation from the rest orientation "
        "in the parent body; axis = along (slide) or about (hinge) the axis, in the "
        "body's frame, from the joint's zero. Quaternions are w, x, y, z.",
        highlight=False,
    )
    if layout.act:
        table = Table(title=f"state.act [{s.na}]: actuator activations", title_justify="left")
        table.add_column("index", justify="right")
        table.add_column("actuator")
        for a in layout.act:
            table.add_row(str(a.index), a.actuator)
        console.print(table)
    else:
        console.print("state.act: empty (no actuator of this model has dynamics)")
    if layout.mocap:
        console.print(
            f"state.mocap_pos [{s.nmocap}, 3] (m) and mocap_quat [{s.nmocap}, 4] "
            f"(w, x, y, z), world frame: bodies the world moves",
            highlight=False,
        )
        table = Table()
        table.add_column("row", justify="right")
        table.add_column("body")
        table.add_column("scenario object")
        for m in layout.mocap:
            table.add_row(str(m.index), m.body, "yes" if m.scenario_object else "no")
        console.print(table)
    else:
        console.print("state.mocap_pos, mocap_quat: empty, shapes [0, 3] and [0, 4]")
    table = Table(
        title=f"command.ctrl [{layout.nu}]: controls (a plan's rows likewise)", title_justify="left"
    )
    for column in ("index", "actuator", "drives", "unit", "range", "safe", "on a safe stop"):
        table.add_column(column, justify="right" if column in ("index", "safe") else "left")
    for c in layout.ctrl:
        table.add_row(
            str(c.index),
            c.actuator,
            c.target,
            c.unit,
            _vector(c.range) if c.range else "unlimited",
            f"{c.safe:g}",
            "keeps its last command" if c.holds_last else "safe value",
        )
    console.print(table)
    if layout.extras:
        table = Table(title="state.extras: named values the world reports", title_justify="left")
        for column in ("name", "unit", "range", "what"):
            table.add_column(column)
        for e in layout.extras:
            table.add_row(e.name, e.unit, _vector(e.range), e.description)
        console.print(table)
    else:
        console.print("state.extras: none needed by this scenario")
    _print_sensors(layout, console)


def _print_sensors(layout: BridgeLayout, console: Console) -> None:
    """The sensors of ``state.scans``, and the objects only they show."""
    if layout.perceived:
        console.print(
            f"perceived objects (not in the state: only the sensors show them): "
            f"{', '.join(layout.perceived)}",
            highlight=False,
        )
    if not layout.sensors:
        console.print("state.scans: none (the scenario declares no sensors)")
        return
    table = Table(
        title="state.scans: the sensors' readings (protocol 3; docs/protocol.md, Scans)",
        title_justify="left",
    )
    for column in ("name", "kind", "ranges", "rate (Hz)", "frame", "pos (m)", "band (m)", "fov"):
        table.add_column(column)
    for s in layout.sensors:
        table.add_row(
            s.name,
            s.kind,
            f"[{', '.join(map(str, s.shape))}]",
            f"{s.rate:g}",
            s.frame,
            _vector(s.pos),
            _vector(s.range),
            f"{s.fov:g}°" + (" vertical" if s.kind == "depth" else ""),
        )
    console.print(table)


def print_frames(frames: tuple[FrameName, ...], console: Console) -> None:
    """The frames a scenario may name, and what each is."""
    console.print(
        "frames: the names cost terms, observers, the success test and metrics may "
        "use (a site as site:NAME)",
        highlight=False,
    )
    table = Table()
    for column in ("name", "kind", "part of"):
        table.add_column(column)
    for f in frames:
        kind = f"{f.kind} ({f.same_as}, the robot's frame)" if f.same_as else f.kind
        table.add_row(f.name, kind, f.part)
    console.print(table)
