"""Session fixtures.

``lockstep_episodes``: the seeded lock-step episodes of every selected test module that declares
``episode_specs(out)`` (tests/test_panda.py, tests/test_push_pull.py), run as ONE pool on the
cores (tests/episodes.py). One pool instead of one per module, because a pool's last episode
runs alone and leaves a core idle; the modules list their longest episodes first for the same
reason. Lock-step episodes do not depend on what else runs, so sharing changes no result.
"""

from __future__ import annotations

import pytest

from tests.episodes import run_episodes


@pytest.fixture(scope="session")
def lockstep_episodes(request, tmp_path_factory):
    modules = []
    for item in request.session.items:
        module = item.module
        if hasattr(module, "episode_specs") and module not in modules:
            modules.append(module)
    out = tmp_path_factory.mktemp("episodes")
    specs = [spec for module in modules for spec in module.episode_specs(out)]
    labels = [label for label, _, _ in specs]
    assert len(set(zip(labels, (s for _, _, s in specs)))) == len(specs), "episode labels collide"
    return run_episodes(specs, out)
