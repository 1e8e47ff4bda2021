"""Background jobs (fitting) on worker threads, with progress, cancellation and a durable record.

A job is a function ``fn(request, progress, should_stop) -> result`` where ``progress(fraction,
stage)`` reports and ``should_stop()`` says the operator cancelled. Every state change goes to the
store first, so the HTTP API and a restarted service see the same record; a job that was running
when the process died is marked ``interrupted`` by :class:`~gcs_pdm.service.storage.Store` at open.
The numba kernel releases the GIL, so threads give real parallelism without process start-up.
"""
from __future__ import annotations

import logging
import threading
from concurrent.futures import Future, ThreadPoolExecutor
from typing import Any, Callable

from gcs_pdm.service.events import EventBus
from gcs_pdm.service.storage import Store

log = logging.getLogger(__name__)

JobFn = Callable[[dict, Callable[[float, str], None], Callable[[], bool]], Any]


class JobCancelled(Exception):
    """Raised inside a job function (or by the runner) when the operator cancelled it."""


class JobRunner:
    def __init__(self, store: Store, events: EventBus | None = None, workers: int = 1):
        self.store = store
        self.events = events or EventBus()
        self._pool = ThreadPoolExecutor(max_workers=workers, thread_name_prefix="job")
        self._cancel: dict[str, threading.Event] = {}
        self._futures: dict[str, Future] = {}
        self._kinds: dict[str, JobFn] = {}
        self._lock = threading.Lock()

    def register(self, kind: str, fn: JobFn) -> None:
        self._kinds[kind] = fn

    @property
    def kinds(self) -> list[str]:
        return sorted(self._kinds)

    def submit(self, kind: str, request: dict) -> str:
        if kind not in self._kinds:
            raise KeyError(f"kind: no job kind {kind!r}; have {', '.join(self.kinds)}")
        job_id = self.store.create_job(kind, request)
        stop = threading.Event()
        with self._lock:
            self._cancel[job_id] = stop
            self._futures[job_id] = self._pool.submit(self._run, job_id, kind, request, stop)
        self.events.publish("job", id=job_id, kind=kind, status="queued", progress=0.0)
        return job_id

    def cancel(self, job_id: str) -> dict:
        job = self.store.job(job_id)  # raises NotFound
        with self._lock:
            stop = self._cancel.get(job_id)
        if job["status"] in ("queued", "running") and stop is not None:
            stop.set()
            if job["status"] == "queued":
                fut = self._futures.get(job_id)
                if fut is not None and fut.cancel():
                    self._finish(job_id, kind=job["kind"], status="cancelled", stage="cancelled before start")
        return self.store.job(job_id)

    def wait(self, job_id: str, timeout: float | None = None) -> dict:
        fut = self._futures.get(job_id)
        if fut is not None:
            try:
                fut.result(timeout=timeout)
            except Exception:  # noqa: BLE001 - the outcome is in the store
                pass
        return self.store.job(job_id)

    def shutdown(self, cancel_running: bool = True) -> None:
        if cancel_running:
            for stop in list(self._cancel.values()):
                stop.set()
        self._pool.shutdown(wait=True, cancel_futures=True)

    # --- worker side ---------------------------------------------------------------------------

    def _finish(self, job_id: str, *, kind: str, status: str, stage: str, result: Any = None,
                error: str | None = None) -> None:
        self.store.update_job(job_id, status=status, stage=stage, result=result, error=error,
                              progress=1.0 if status == "succeeded" else None)
        self.events.publish("job", id=job_id, kind=kind, status=status, stage=stage, error=error)
        with self._lock:
            self._cancel.pop(job_id, None)

    def _run(self, job_id: str, kind: str, request: dict, stop: threading.Event) -> None:
        if stop.is_set():
            self._finish(job_id, kind=kind, status="cancelled", stage="cancelled before start")
            return
        self.store.update_job(job_id, status="running", stage="starting")
        self.events.publish("job", id=job_id, kind=kind, status="running", progress=0.0)
        last = [-1.0]

        def progress(fraction: float, stage: str = "") -> None:
            fraction = min(max(float(fraction), 0.0), 1.0)
            # The store and the bus see at most ~100 updates per job, however chatty the fitter.
            if fraction - last[0] >= 0.01 or fraction >= 1.0:
                last[0] = fraction
                self.store.update_job(job_id, progress=fraction, stage=stage or "running")
                self.events.publish("job", id=job_id, kind=kind, status="running", progress=fraction, stage=stage)

        try:
            result = self._kinds[kind]({**request, "_job_id": job_id}, progress, stop.is_set)
        except JobCancelled:
            self._finish(job_id, kind=kind, status="cancelled", stage="cancelled")
            return
        except Exception as exc:  # noqa: BLE001 - a failing job is recorded, the service lives on
            log.exception("job %s (%s) failed", job_id, kind)
            self._finish(job_id, kind=kind, status="failed", stage="failed", error=f"{type(exc).__name__}: {exc}")
            return
        if stop.is_set():
            self._finish(job_id, kind=kind, status="cancelled", stage="cancelled", result=result)
        else:
            self._finish(job_id, kind=kind, status="succeeded", stage="done", result=result)
