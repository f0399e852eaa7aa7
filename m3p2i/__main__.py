"""``python -m m3p2i ...`` is the ``m3p2i`` command (the launcher starts the view this way,
with the same interpreter as the episode)."""

from m3p2i.cli import app

app()
