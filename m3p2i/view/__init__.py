"""``m3p2i view``: the world and the planner in a browser, live or replayed from an episode log.

Live, it is a read-only subscriber: it connects to the world's ``state`` socket and the
planner's ``diagnostics`` socket (PUB/SUB, so the planner never waits for it) and sends only
the ``control`` ops a user asks for (pause, resume, reset, move an object). Replay reads an
episode log (and the ``diagnostics.jsonl`` beside it, when the live view recorded one).

The page is served by viser (the optional extra ``m3p2i[view]``): its web client ships inside
the wheel, so the page loads with no network beyond the machine serving it. The drawing is
:mod:`m3p2i.view_scene` (pure: the model's geoms as meshes, their poses).

Modules: ``page`` (the web server and its origin guard), ``drawing`` (scene, trajectories,
panel), ``perception`` (the sensors' points and the planner's distance map, and their records),
``live`` (the live page and its controls), ``playback`` (the replay page)."""

from m3p2i.view.drawing import (
    MODE_COLOURS,
    PanelInfo,
    SceneDrawing,
    path_segments,
    robot_frame,
    trajectory_segments,
    weight_bar,
)
from m3p2i.view.live import ControlClient, LiveView, diagnostics_record
from m3p2i.view.page import OriginPolicy, import_viser, viser_server
from m3p2i.view.playback import ReplayView, action_timeline, load_replay, metrics_text
