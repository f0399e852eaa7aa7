"""``python -m shared.tools ...`` is the ``m3p2i`` command (the launcher starts the view this way,
with the same interpreter as the episode)."""

from shared.tools.cli import app

app()
