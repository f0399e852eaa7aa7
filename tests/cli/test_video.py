"""``m3p2i record``'s pieces: which logged steps become frames, and an offscreen render of a
hand-made log with a sampled trajectory drawn (skipped where no headless OpenGL exists)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from m3p2i import video
from tests.server.test_metrics import hand_made_log, scenario  # noqa: F401  (fixture)


def test_frame_steps_follow_fps_and_speed():
    times = np.arange(1, 101) * 0.01  # 1 s of a 0.01 s world
    assert video.frame_steps(times, fps=20, speed=1.0) == list(range(0, 100, 5)) + [99]
    assert video.frame_steps(times, fps=10, speed=0.5) == list(range(0, 100, 5)) + [99]
    assert video.frame_steps(np.array([]), fps=20, speed=1.0) == []


@pytest.mark.slow
def test_render_a_logged_episode_with_its_sampled_trajectories(scenario, tmp_path):  # noqa: F811
    try:
        backend = video.gl_backend()
    except video.NoGLError as exc:
        pytest.skip(str(exc))
    run = tmp_path / "run"
    run.mkdir()
    records = hand_made_log(scenario)
    (run / "episode.jsonl").write_text("".join(json.dumps(r) + "\n" for r in records))
    path = np.stack([np.linspace(-3, 3, 15), np.full(15, -2.0), np.full(15, 0.3)], axis=1)
    (run / video.DIAGNOSTICS_FILE).write_text(json.dumps({"seq": 1, "top": [path.tolist()]}) + "\n")
    out = tmp_path / "episode.gif"
    video.render_in_child(backend, run, out, width=480, height=360, fps=20, speed=1.0)

    from PIL import Image

    gif = Image.open(out)
    assert gif.n_frames == 7 and gif.size == (480, 360)
    rgb = np.asarray(gif.convert("RGB")).astype(int)
    green = (
        (rgb[..., 1] > 120) & (rgb[..., 1] > rgb[..., 0] + 60) & (rgb[..., 1] > rgb[..., 2] + 60)
    )
    assert green.sum() > 20, "the sampled trajectory is not drawn"
