"""What the argparse measuring scripts check of their options before they measure anything
(the typer ones check scenarios with :func:`m3p2i.cli_support.scenarios_or_exit`)."""

from __future__ import annotations

import argparse


def positive_int(text: str) -> int:
    """An argparse type: an integer >= 1."""
    value = int(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected an integer >= 1, got {value}")
    return value
