"""gcs_pdm.compiled's groups (issue 33): each group's probe, the function whose cache says whether
the group is compiled, is a cached numba function, so a warm cache is seen as warm (a probe that is
no longer compiled would make every replay and demo recompile its group in a child process)."""
from __future__ import annotations

import importlib

from numba.core.registry import CPUDispatcher

from gcs_pdm import compiled


def test_every_group_has_a_probe_that_numba_caches():
    assert set(compiled._PROBES) == set(compiled.GROUPS)
    assert set(compiled.DEMO_GROUPS) <= set(compiled.GROUPS) and set(compiled.REPLAY_GROUPS) <= set(compiled.GROUPS)
    for group, (module, name) in compiled._PROBES.items():
        probe = getattr(importlib.import_module(module), name)
        assert isinstance(probe, CPUDispatcher), f"{group}: {module}.{name} is not a compiled function"
        assert probe._cache._cache_file is not None, f"{group}: {module}.{name} is not cached (cache=True)"
