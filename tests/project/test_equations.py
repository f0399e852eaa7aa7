"""docs/equations.md: every paper/thesis equation it lists leads to code that exists."""

from __future__ import annotations

import importlib
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
TABLE = ROOT / "docs" / "equations.md"
PACKAGES = ("planner_client.", "shared.", "server.")


def rows() -> dict[str, list[str]]:
    """``{"paper Eq. 12": [backticked names and paths], ...}`` from the table."""
    out = {}
    for line in TABLE.read_text().splitlines():
        m = re.match(r"^\| ((?:paper|thesis) (?:Eq|Alg)\. [\d.]+) \| (.+) \|$", line)
        if m:
            assert m.group(1) not in out, f"{m.group(1)} listed twice"
            out[m.group(1)] = re.findall(r"`([^`]+)`", m.group(2))
    return out


def resolve(dotted: str):
    """Import the longest importable module prefix of ``dotted``, then getattr the rest."""
    parts = dotted.split(".")
    for i in range(len(parts), 0, -1):
        try:
            obj = importlib.import_module(".".join(parts[:i]))
        except ModuleNotFoundError:
            continue
        for name in parts[i:]:
            obj = getattr(obj, name)
        return obj
    raise ModuleNotFoundError(dotted)


def test_the_table_covers_the_paper_and_the_thesis():
    table = rows()
    assert {f"paper Eq. {n}" for n in range(1, 34)} <= set(table)
    assert {"thesis Eq. 2.15", "paper Alg. 2", "thesis Alg. 2"} <= set(table)


@pytest.mark.parametrize("equation, names", sorted(rows().items()))
def test_every_listed_name_exists(equation, names):
    code = [n for n in names if n.startswith(PACKAGES)]
    files = [n for n in names if "/" in n]
    assert code or files, f"{equation} names no code"
    for name in code:
        resolve(name)  # raises when a module or attribute is gone
    for path in files:
        assert (ROOT / path).is_file(), path


def test_resolve_fails_on_a_missing_name():
    with pytest.raises(AttributeError):
        resolve("planner_client.mppi.m3p2i.NoSuchThing")
