"""Evaluation: per-episode metrics (paper Tables I-III) and reading episode logs back.

The server's episode summary uses it, as do the tools; it never imports :mod:`m3p2i`."""
