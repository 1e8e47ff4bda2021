"""The replay's trace flies its cut-off Monte Carlo on a worker thread (``TracedPipeline``,
``background=True``): the trace must be the serial one, number for number; a failure on the
worker must surface as an error, not a hang or a silently missing value; no worker outlives the
replay. And the held-current flight's compiled chunk loop must be the whole-horizon kernel run."""
from __future__ import annotations

import dataclasses
import subprocess
import sys
import threading
from pathlib import Path

import numpy as np
import pytest

from gcs_pdm.estimation import prediction
from gcs_pdm.mavlink.mapping import FrameMapper
from gcs_pdm.mavlink.replay import replay_tlog
from gcs_pdm.models import kernel
from gcs_pdm.models.params import PACK_NAMES, default_set, extended_default
from gcs_pdm.replay.vehicle import TracedPipeline, replay_vehicle
from gcs_pdm.mavlink.vehicle_mapping import envelope, frame_mapping

REPO = Path(__file__).resolve().parents[1]
FLIGHT = REPO / "fixtures" / "flights" / "fault_01.tlog"
WORKER = "replay-trace"


def _workers() -> list[threading.Thread]:
    return [t for t in threading.enumerate() if t.name.startswith(WORKER)]


def _replay(background: bool) -> dict:
    desc, about = replay_vehicle(FLIGHT, None)
    consumer = TracedPipeline(desc, about, background=background)
    try:
        return replay_tlog(FLIGHT, mapper=FrameMapper(frame_mapping(desc), envelope=envelope(desc)),
                           frame_consumer=consumer).to_dict()["consumer"]
    finally:
        consumer.close()


def test_threaded_trace_is_the_serial_trace():
    serial, threaded = _replay(background=False), _replay(background=True)
    predicted = [p["time_to_cutoff_s"] for s in serial["trace"] for p in s["packs"].values()
                 if p["time_to_cutoff_s"] is not None]
    assert len(predicted) >= 10  # the flight draws: the Monte Carlo ran, on the worker in the second replay
    assert threaded["trace"] == serial["trace"]
    assert threaded == serial
    assert not _workers()


def test_a_failure_on_the_worker_is_raised_by_report_and_stops_the_worker(monkeypatch):
    def broken(self):
        raise FloatingPointError("injected in the trace's flight")

    monkeypatch.setattr(prediction.HeldCurrentSamples, "fly", broken)
    desc, about = replay_vehicle(FLIGHT, None)
    consumer = TracedPipeline(desc, about, background=True)
    with pytest.raises(FloatingPointError, match="injected"):
        replay_tlog(FLIGHT, mapper=FrameMapper(frame_mapping(desc), envelope=envelope(desc)), frame_consumer=consumer)
    assert not _workers()


def test_after_close_samples_predict_on_the_calling_thread():
    desc, about = replay_vehicle(FLIGHT, None)
    consumer = TracedPipeline(desc, about, background=True)
    assert len(_workers()) <= 1  # started lazily by the first submission, or at once
    consumer.close()
    assert not _workers()
    # closed before any frame: the whole replay predicts on this thread, as the serial consumer
    summary = replay_tlog(FLIGHT, mapper=FrameMapper(frame_mapping(desc), envelope=envelope(desc)),
                          frame_consumer=consumer).to_dict()["consumer"]
    assert summary["trace"] == _replay(background=False)["trace"]


def _command(code: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=REPO, timeout=300)


def test_the_replay_command_exits_cleanly_and_a_worker_failure_is_an_error_not_a_hang():
    ok = _command("import sys, threading; from gcs_pdm.cli import main\n"
                  f"rc = main(['replay', {str(FLIGHT)!r}, '--json'])\n"
                  f"assert not [t for t in threading.enumerate() if t.name.startswith({WORKER!r})]\n"
                  "sys.exit(rc)")
    assert ok.returncode == 0, ok.stderr
    failed = _command("import sys\nfrom gcs_pdm.estimation import prediction\n"
                      "def broken(self): raise FloatingPointError('injected in the trace flight')\n"
                      "prediction.HeldCurrentSamples.fly = broken\n"
                      "from gcs_pdm.cli import main\n"
                      f"sys.exit(main(['replay', {str(FLIGHT)!r}, '--json']))")
    assert failed.returncode != 0 and "FloatingPointError: injected in the trace flight" in failed.stderr
    assert failed.stdout == ""


def _whole_horizon(variant: str, params: np.ndarray, x0: np.ndarray, dt: np.ndarray, current: np.ndarray,
                   cutoff: np.ndarray, ambient: float) -> tuple[np.ndarray, np.ndarray]:
    """(end step, peak temperature to it) of each row from one kernel call over the whole horizon."""
    run = kernel.simulate_packs(params, x0, dt, np.repeat(current[:, None], dt.size, axis=1), ambient, variant=variant)
    ended = (run.voltage < cutoff[:, None]) | (run.soc <= 0.0)
    reached = ended.any(axis=1)
    k_end = np.where(reached, ended.argmax(axis=1), dt.size - 1)
    peak = np.max(np.where(np.arange(dt.size) <= k_end[:, None], run.temperature, -np.inf), axis=1)
    return np.where(reached, k_end, -1), peak


@pytest.mark.parametrize("variant", ["paper", "extended"])
def test_the_compiled_chunk_loop_is_the_whole_horizon_run(variant):
    rng = np.random.default_rng(5)
    ps = default_set()
    n = 4 * 40
    if variant == "paper":
        base = ps.pack_matrix()
        params = np.repeat(base, 40, axis=0) * np.exp(rng.normal(0.0, 0.05, (n, base.shape[1])))
        x0 = kernel.initial_pack_state(params, rng.uniform(0.05, 1.0, n), 25.0)
    else:
        base = np.stack([dataclasses.replace(ps.packs[p], model="extended", extended=extended_default("lipo"))
                         .extended_vector() for p in PACK_NAMES])
        params = np.repeat(base, 40, axis=0) * np.exp(rng.normal(0.0, 0.03, (n, base.shape[1])))
        x0 = kernel.initial_extended_state(params, rng.uniform(0.05, 1.0, n), 20.0, 0.0)
    current = rng.uniform(0.0, 60.0, n)
    current[::9] = 0.0  # rows that never reach their cut-off
    cutoff = np.full(n, 18.0)
    dt = np.full(300, 5.0)
    got = prediction._held_current_to_cutoff(params, x0, dt, current, cutoff, 20.0, variant)
    want = _whole_horizon(variant, params, x0, dt, current, cutoff, 20.0)
    assert (want[0] >= 0).any() and (want[0] < 0).any() and (want[0] > prediction._CUTOFF_CHUNK_STEPS).any()
    np.testing.assert_array_equal(got[0], want[0])
    np.testing.assert_array_equal(got[1], want[1])
