"""Generated Markdown blocks: ``<!-- TAG ARGS -->`` ... ``<!-- end of END -->``, the text between
regenerated from what ARGS name (results files), so that no table in README or docs is typed:
``m3p2i report --update``, ``scripts/soak.py --update`` and ``scripts/benchmark.py --update``
each own one tag."""

from __future__ import annotations

import re
from collections.abc import Callable


def regenerate(text: str, tag: str, end: str, render: Callable[[str], str]) -> tuple[str, int]:
    """``text`` with the body of every ``<!-- TAG ARGS -->`` block up to its ``<!-- end of
    END -->`` replaced by ``render(ARGS)`` (stripped), and how many blocks there were."""
    pattern = re.compile(
        rf"(<!-- {re.escape(tag)} (?P<args>[^>]*?) -->\n)(?P<body>.*?)"
        rf"(<!-- end of {re.escape(end)} -->)",
        re.S,
    )
    return pattern.subn(lambda m: m.group(1) + render(m["args"].strip()) + m.group(4), text)
