"""The `m3p2i` command and what only it uses: launcher, bench, reports, plots, video.

Neither process imports this package; it starts them as `python -m server` and
`python -m planner_client` and meets them only over the wire and through their logs."""
