"""Generated Markdown blocks: ``<!-- TAG ARGS -->`` ... ``<!-- end of END -->``, the text between
regenerated from what ARGS name (results files), so that no table in README or docs is typed:
``m3p2i report --update``, ``scripts/soak.py --update`` and ``scripts/benchmark.py --update``
each own one tag."""

from __future__ import annotations

import json
import re
from collections.abc import Callable
from pathlib import Path

import typer


def regenerate(
    text: str, tag: str, end: str, render: Callable[[str], str | None]
) -> tuple[str, int]:
    """``text`` with the body of every ``<!-- TAG ARGS -->`` block up to its ``<!-- end of
    END -->`` replaced by ``render(ARGS)`` (stripped; None keeps the body), and how many
    blocks there were."""
    pattern = re.compile(
        rf"(<!-- {re.escape(tag)} (?P<args>[^>]*?) -->\n)(?P<body>.*?)"
        rf"(<!-- end of {re.escape(end)} -->)",
        re.S,
    )

    def block(m: re.Match) -> str:
        body = render(m["args"].strip())
        return m.group(1) + (m["body"] if body is None else body) + m.group(4)

    return pattern.subn(block, text)


def read_results(path: Path, what: str) -> dict:
    """The JSON results file ``path`` (``what``: where it was named, for the message), or a
    ``typer.BadParameter`` that names it and says what was expected."""
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise typer.BadParameter(f"{what}: no file {path} (expected a results file)") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise typer.BadParameter(f"{what}: {path} is not a JSON results file ({exc})") from None


def read_doc(path: Path, flag: str = "--update") -> str:
    """The Markdown file ``path`` whose blocks are to be regenerated, or a
    ``typer.BadParameter`` naming ``flag`` when it cannot be read."""
    try:
        return path.read_text(encoding="utf-8")
    except OSError as exc:
        raise typer.BadParameter(f"cannot read {path}: {exc}", param_hint=flag) from None
