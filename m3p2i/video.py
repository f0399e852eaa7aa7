"""Offscreen video of an episode: the logged states rendered with ``mujoco.Renderer``, the
planner's best sampled trajectories (its ``diagnostics`` stream, port + 3) drawn in green, written
as GIF (Pillow) or MP4 (an ``ffmpeg`` executable).

Rendering needs an OpenGL context without a display: EGL (GPU drivers or Mesa, ``libegl1``) or
OSMesa (software, ``libosmesa6``). MuJoCo picks the backend from ``MUJOCO_GL`` when it is first
imported, so rendering runs in a child process, ``python -m m3p2i.video``, started with the
first backend that works (:func:`gl_backend`). ``m3p2i record`` drives all of it.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import threading
from itertools import pairwise
from pathlib import Path

import mujoco
import numpy as np
import typer
import zmq

from m3p2i.cli_support import VIDEO_FORMATS, Fps, Height, Speed, Width, usage_error
from planner_client.keys import PlannerKeys, curve_client
from server.evaluation import log_reader
from shared import protocol as P
from shared.config import ConfigError
from shared.endpoints import Endpoints, socket

GL_BACKENDS = ("egl", "osmesa")
DIAGNOSTICS_FILE = "diagnostics.jsonl"
TOP_RGBA = np.array([0.1, 0.85, 0.2, 0.9], dtype=np.float32)

_PROBE = (
    "import mujoco; m = mujoco.MjModel.from_xml_string('<mujoco/>'); "
    "mujoco.Renderer(m, 8, 8).render()"
)


class NoGLError(RuntimeError):
    """No headless OpenGL backend works on this machine."""


def gl_backend() -> str:
    """``MUJOCO_GL`` when set, else the first of EGL, OSMesa that renders a test frame."""
    candidates = [os.environ["MUJOCO_GL"]] if os.environ.get("MUJOCO_GL") else list(GL_BACKENDS)
    errors = []
    for backend in candidates:
        probe = subprocess.run(
            [sys.executable, "-c", _PROBE],
            capture_output=True,
            text=True,
            env={**os.environ, "MUJOCO_GL": backend},
            timeout=120,
            check=False,
        )
        if probe.returncode == 0:
            return backend
        last = (probe.stderr.strip().splitlines() or ["(no output)"])[-1]
        errors.append(f"MUJOCO_GL={backend}: {last}")
    raise NoGLError(
        "no headless OpenGL for MuJoCo's renderer (" + "; ".join(errors) + "). "
        "Install EGL (GPU driver, or Mesa: apt-get install libegl1 libgl1-mesa-dri) "
        "or OSMesa (apt-get install libosmesa6), or set MUJOCO_GL to a backend "
        "that works here"
    )


class DiagnosticsRecorder:
    """Subscribes to a planner's diagnostics and appends ``{seq, top}`` lines to a file, on a
    thread, until :meth:`close`. Start it before the planner: PUB/SUB drops what is sent before
    the subscription is in place."""

    def __init__(
        self, port: int, path: Path, host: str = "127.0.0.1", keys: PlannerKeys | None = None
    ):
        self.path = path
        self._stop = threading.Event()
        self._ctx = zmq.Context()
        self._sub = socket(self._ctx, zmq.SUB)  # the project's size limit and no linger
        self._sub.setsockopt(zmq.SUBSCRIBE, b"")
        if keys is not None:  # a tool beside the planner: its key pair, the planner as server
            curve_client(self._sub, keys.own, keys.own.public)
        self._sub.connect(Endpoints(host, port).diagnostics)
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        with self.path.open("w") as f:
            while not self._stop.is_set():
                if not self._sub.poll(100):
                    continue
                try:
                    msg = P.decode(self._sub.recv(), expect="diagnostics")
                except P.ProtocolError:
                    continue  # a viewer-side recorder ignores what it cannot read
                f.write(
                    json.dumps(
                        {"seq": msg.seq, "action": msg.action, "top": np.round(msg.top, 4).tolist()}
                    )
                    + "\n"
                )

    def close(self) -> None:
        self._stop.set()
        self._thread.join()
        self._sub.close(0)
        self._ctx.term()


def read_tops(path: Path) -> dict[int, np.ndarray]:
    """seq -> ``[M, T, 3]`` best sampled trajectories, from a diagnostics file (empty if none)."""
    if not path.is_file():
        return {}
    records = log_reader.read_log(path)  # a view's records of scans and fields have a kind
    return {r["seq"]: np.asarray(r["top"], dtype=float) for r in records if "kind" not in r}


# ------------------------------------------------------------------------------ rendering (child)


def frame_steps(times: np.ndarray, fps: float, speed: float) -> list[int]:
    """Indices of the logged steps to show: one per ``speed / fps`` simulated seconds, last
    step included."""
    if len(times) == 0:
        return []
    picks, next_t = [], times[0]
    for i, t in enumerate(times):
        if t >= next_t - 1e-9:
            picks.append(i)
            next_t = t + speed / fps
    if picks[-1] != len(times) - 1:
        picks.append(len(times) - 1)
    return picks


def _camera(model: mujoco.MjModel, arena: float | None, focus: np.ndarray) -> mujoco.MjvCamera:
    """Mobile scenes: the whole arena from almost straight above. Others (an arm on a table):
    the ``focus`` points (robot and goal at the start) from the front and above; the model's own
    extent would include the whole floor."""
    cam = mujoco.MjvCamera()
    mujoco.mjv_defaultFreeCamera(model, cam)
    if arena:
        cam.lookat[:] = (0.0, 0.0, 0.0)
        cam.distance, cam.elevation, cam.azimuth = 2.6 * arena, -85.0, 90.0
    else:
        cam.lookat[:] = focus.mean(axis=0)
        spread = float(np.ptp(focus, axis=0).max())
        cam.distance, cam.elevation, cam.azimuth = max(1.2, 3.0 * spread), -25.0, 150.0
    return cam


def _draw_paths(scene: mujoco.MjvScene, paths: np.ndarray, radius: float) -> None:
    """Append the sampled trajectories to the scene as thin capsules (best first, brightest)."""
    for k, path in enumerate(paths):
        rgba = TOP_RGBA * np.array([1, 1, 1, 1.0 if k == 0 else 0.5], dtype=np.float32)
        for a, b in pairwise(path):
            if scene.ngeom >= scene.maxgeom:
                return
            g = scene.geoms[scene.ngeom]
            mujoco.mjv_initGeom(
                g, mujoco.mjtGeom.mjGEOM_CAPSULE, np.zeros(3), np.zeros(3), np.eye(3).ravel(), rgba
            )
            mujoco.mjv_connector(g, mujoco.mjtGeom.mjGEOM_CAPSULE, radius, a, b)
            scene.ngeom += 1


def render_frames(
    log: Path, scenario: str | None, width: int, height: int, fps: float, speed: float
) -> list[np.ndarray]:
    """RGB frames of a logged episode, with the trajectories of ``diagnostics.jsonl`` beside it."""
    from server.evaluation.replay import load_step, resolve_frame
    from shared.scene import compile_model

    records = log_reader.read_log(log)
    sc = log_reader.log_scenario(records, scenario)
    steps = log_reader.steps(records)
    if not steps:
        raise ValueError(f"{log}: the episode log has no steps")
    tops = read_tops(log.parent / DIAGNOSTICS_FILE)
    model = compile_model(sc)
    # the scene's sun plus MuJoCo's headlight wash a light floor out to white from above
    model.vis.headlight.diffuse[:] = 0.25
    model.light_diffuse[:] *= 0.6
    model.vis.global_.offwidth = max(model.vis.global_.offwidth, width)
    model.vis.global_.offheight = max(model.vis.global_.offheight, height)
    data = mujoco.MjData(model)
    load_step(model, data, steps[0])
    names = ["robot"] + (
        [sc.metrics.position.a, sc.metrics.position.b] if sc.metrics.position else []
    )
    focus = np.array([resolve_frame(sc, model, n, "metrics.position").pos(data) for n in names])
    arena = sc.world.arena.half_size if sc.world.arena else None
    cam = _camera(model, arena, focus)
    radius = 0.02 if arena else 0.002  # about 2 pixels across at 480 x 360
    frames = []
    with mujoco.Renderer(model, height, width, max_geom=model.ngeom + 2000) as renderer:
        for i in frame_steps(np.array([s["time"] for s in steps]), fps, speed):
            load_step(model, data, steps[i])
            renderer.update_scene(data, cam)
            # the plan made at this state (seq), else the last one before it
            seq = max((s for s in tops if s <= steps[i]["seq"]), default=None)
            if seq is not None:
                _draw_paths(renderer.scene, tops[seq], radius)
            frames.append(renderer.render().copy())
    return frames


def write_video(frames: list[np.ndarray], out: Path, fps: float) -> Path:
    """GIF through Pillow, MP4 through an ffmpeg executable (PATH, or imageio-ffmpeg's)."""
    out.parent.mkdir(parents=True, exist_ok=True)
    if out.suffix.lower() == ".gif":
        from PIL import Image

        # octree keeps small saturated objects (a robot, the green paths) that Pillow's default
        # median cut merges into the floor's greys
        images = [
            Image.fromarray(f).quantize(256, method=Image.Quantize.FASTOCTREE) for f in frames
        ]
        images[0].save(
            out,
            save_all=True,
            append_images=images[1:],
            loop=0,
            duration=max(20, round(1000 / fps)),
        )
        return out
    if out.suffix.lower() != ".mp4":
        raise ValueError(f"{out}: unknown video format (expected {' or '.join(VIDEO_FORMATS)})")
    exe = shutil.which("ffmpeg")
    if exe is None:
        try:
            import imageio_ffmpeg

            exe = imageio_ffmpeg.get_ffmpeg_exe()
        except ImportError:
            raise RuntimeError(
                "MP4 needs ffmpeg: apt-get install ffmpeg, or "
                "pip install imageio-ffmpeg; or write a .gif"
            ) from None
    h, w = frames[0].shape[:2]
    cmd = [
        exe,
        "-y",
        "-loglevel",
        "error",
        "-f",
        "rawvideo",
        "-pix_fmt",
        "rgb24",
        "-s",
        f"{w}x{h}",
        "-r",
        f"{fps}",
        "-i",
        "-",
        "-pix_fmt",
        "yuv420p",
        "-vcodec",
        "libx264",
        str(out),
    ]
    subprocess.run(cmd, input=b"".join(f.tobytes() for f in frames), check=True)
    return out


def main(
    log: Path = typer.Argument(..., help="Episode log or its run folder."),
    out: Path = typer.Argument(..., help="Video file: .gif or .mp4."),
    scenario: str | None = typer.Option(None, help="Scenario (default: the log's)."),
    width: Width = 480,
    height: Height = 360,
    fps: Fps = 20.0,
    speed: Speed = 1.0,
) -> None:
    """Render an episode log to a video (run with MUJOCO_GL set; ``m3p2i record`` does that)."""
    try:
        frames = render_frames(log_reader.find_log(log), scenario, width, height, fps, speed)
        typer.echo(f"wrote {write_video(frames, out, fps)} ({len(frames)} frames)")
    except (ConfigError, FileNotFoundError, ValueError, RuntimeError) as exc:
        usage_error(str(exc))


def render_in_child(
    backend: str, log: Path, out: Path, width: int, height: int, fps: float, speed: float
) -> None:
    """Run :func:`main` in a child process with ``MUJOCO_GL=backend``; raises on failure."""
    cmd = [
        sys.executable,
        "-m",
        "m3p2i.video",
        str(log),
        str(out),
        "--width",
        str(width),
        "--height",
        str(height),
        "--fps",
        str(fps),
        "--speed",
        str(speed),
    ]
    done = subprocess.run(
        cmd, env={**os.environ, "MUJOCO_GL": backend}, capture_output=True, text=True, check=False
    )
    if done.returncode != 0:
        raise RuntimeError(f"rendering failed (MUJOCO_GL={backend}):\n{done.stderr.strip()}")


if __name__ == "__main__":
    typer.run(main)
