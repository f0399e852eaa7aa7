"""``m3p2i-planner`` and ``python -m planner_client``: the planner process's entry point."""

import gc
import os


def main() -> None:
    """Run the planner CLI. Before anything imports them: the planner never draws, so MuJoCo
    loads no OpenGL library (GLFW: 40 ms of its start-up), and torch loads no third-party device
    backends (it scans every installed package's entry points for them); a value the operator
    set is kept.

    The garbage collector is off until the planner is built (the CLI turns it back on:
    :func:`shared.cli_common.collector_back`)."""
    gc.disable()
    os.environ.setdefault("MUJOCO_GL", "disable")
    os.environ.setdefault("TORCH_DEVICE_BACKEND_AUTOLOAD", "0")
    from planner_client.phases import STARTUP

    STARTUP.start()
    from planner_client.cli import app

    app(prog_name="m3p2i-planner")


if __name__ == "__main__":
    main()
