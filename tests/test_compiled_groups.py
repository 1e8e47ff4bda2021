"""gcs_pdm.compiled's groups (issue 33): each group's probe, the function whose cache says whether
the group is compiled, is a cached numba function, so a warm cache is seen as warm (a probe that is
no longer compiled would make every replay and demo recompile its group in a child process)."""
from __future__ import annotations

import importlib

from numba.core.registry import CPUDispatcher

from gcs_pdm.replay.warm_up import REPLAY_GROUPS
from gcs_pdm.service.warm_up import DEMO_GROUPS


def test_every_group_has_a_probe_that_numba_caches():
    assert set(REPLAY_GROUPS) <= set(DEMO_GROUPS)
    assert len({g.name for g in DEMO_GROUPS}) == len(DEMO_GROUPS)
    for group in DEMO_GROUPS:
        module, name = group.probe
        probe = getattr(importlib.import_module(module), name)
        assert isinstance(probe, CPUDispatcher), f"{group.name}: {module}.{name} is not a compiled function"
        assert probe._cache._cache_file is not None, f"{group.name}: {module}.{name} is not cached (cache=True)"
