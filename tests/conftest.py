"""Session fixtures.

``lockstep_episodes``: the seeded lock-step episodes of every module whose selected tests read
them and that declares ``episode_specs(out)`` (tests/e2e/test_panda.py,
tests/e2e/test_push_pull.py), run as ONE pool (tests/episodes.py) that starts with the session,
in a child process at the lowest CPU priority, so that its minutes of episodes fill the cores
the other tests leave idle. The tests that read the episodes run last, when the pool has had
the whole suite's time; one pool instead of one per module, because a pool's last episode runs
alone and leaves a core idle (the modules list their longest episodes first for the same
reason). Lock-step episodes do not depend on what else runs, so sharing and running them beside
other tests changes no result.

The tests live by package (shared/, planner_client/, server/, cli/ for the m3p2i command,
scripts/ for scripts/measure/, project/ for what spans the repository), the end-to-end runs of
both processes in e2e/; their helpers and data stay here.
"""

from __future__ import annotations

import compileall
import sys
from pathlib import Path

import pytest

from m3p2i.provenance import machine, versions
from tests.episodes import BackgroundEpisodes

POOL = "lockstep_episodes"


def pytest_sessionstart(session):
    """The tests start hundreds of world and planner processes. With ``PYTHONDONTWRITEBYTECODE``
    set (as on this project's CI machines) each would compile the project's ~110 modules from
    source, 0.2-0.3 s of every start (a quarter of the CLI tests' time); they are compiled once
    here instead, into the ``__pycache__`` folders Python itself writes without that setting."""
    if sys.dont_write_bytecode:
        root = Path(__file__).resolve().parents[1]
        for package in ("shared", "server", "planner_client", "m3p2i", "scripts"):
            compileall.compile_dir(root / package, quiet=1)


def pytest_collection_modifyitems(config, items):
    """The tests reading the pool's episodes last (a stable sort: each group keeps its order)."""
    items.sort(key=lambda item: POOL in getattr(item, "fixturenames", ()))


@pytest.fixture(scope="session", autouse=True)
def _lockstep_pool(request, tmp_path_factory):
    """Starts the pool of the selected tests' episodes at once (none where no selected test
    reads them) and stops it if the session ends first."""
    modules = []
    for item in request.session.items:
        if POOL in getattr(item, "fixturenames", ()) and item.module not in modules:
            modules.append(item.module)
    if not modules:
        yield None
        return
    out = tmp_path_factory.mktemp("episodes")
    specs = [spec for module in modules for spec in module.episode_specs(out)]
    labels = [(label, seed) for label, _, seed in specs]
    assert len(set(labels)) == len(specs), "episode labels collide"
    pool = BackgroundEpisodes(specs, out)
    yield pool
    pool.stop()


@pytest.fixture(scope="session")
def lockstep_episodes(_lockstep_pool):
    return _lockstep_pool.result()


def pytest_report_header(config):
    """The machine and the library versions at the top of every run (CI's log included): an
    episode's digits depend on both."""
    return f"m3p2i on {machine()}: {versions()}"
