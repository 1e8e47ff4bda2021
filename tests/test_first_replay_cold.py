"""A replay's first run on a cold numba cache (issue 33): it runs interpreted at once, compiling
nothing in the foreground, while the models compile in the background for the next run, and it
prints the summary a compiled run prints."""
from __future__ import annotations

import json
import logging
import os
import subprocess
import sys
from pathlib import Path

from gcs_pdm import compiled
from gcs_pdm.cli import main as cli_main

REPO = Path(__file__).resolve().parents[1]
FLIGHT = REPO / "fixtures" / "flights" / "fault_03.tlog"  # the shortest recorded flight with a fault
TIMING = ("elapsed_s", "messages_per_s")


def test_cold_replay_runs_interpreted_with_the_compiled_numbers(tmp_path, capsys):
    cache = tmp_path / "numba"
    env = dict(os.environ, NUMBA_CACHE_DIR=str(cache),
               PYTHONPATH=os.pathsep.join([str(REPO), *filter(None, [os.environ.get("PYTHONPATH")])]))
    env.pop("NUMBA_DISABLE_JIT", None)
    # as if an earlier cold run's background compilation were still going: this run starts none
    # (the suite does not pay a minute of compiling), and says so
    lock = compiled._try_lock(compiled._lock_path(str(cache)))
    assert lock is not None
    try:
        cold = subprocess.run([sys.executable, "-m", "gcs_pdm.cli", "replay", str(FLIGHT), "--json"], env=env,
                              capture_output=True, text=True, timeout=300)
    finally:
        lock.close()
    assert cold.returncode == 0, cold.stderr[-2000:]
    assert "the models run interpreted this time" in cold.stderr
    assert "finish compiling in the background (started by an earlier run)" in cold.stderr
    assert not list(cache.rglob("*.nbi")), "the cold run compiled in the foreground"

    logging.disable(logging.WARNING)
    try:
        status = cli_main(["replay", str(FLIGHT), "--json"])  # in-process: compiled (the suite's cache)
    finally:
        logging.disable(logging.NOTSET)
    assert status == 0
    compiled_summary = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    interpreted_summary = json.loads(cold.stdout.strip().splitlines()[-1])
    # the trace's held-current predictions ran (estimation.held_current_arrays when interpreted)
    assert any(p["time_to_cutoff_s"] for entry in interpreted_summary["consumer"]["trace"]
               for p in entry["packs"].values())
    for key in TIMING:
        compiled_summary.pop(key)
        interpreted_summary.pop(key)
    assert interpreted_summary == compiled_summary
