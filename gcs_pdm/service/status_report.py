"""What the link refused to believe, for ``/status`` and ``/health``, and the operator's alert when
another system sends vehicle heartbeats on our link; which packs no longer match their model
(``model_mismatch_summary``).

The link (gcs_pdm.mavlink.connection.Link) already counts everything it gates: foreign systems,
rejected timestamps, values outside the physical envelope, undecodable packets. This module only
reads that report (``Link.trust_report()``) for the HTTP answers and turns each newly heard foreign
system into one ``foreign_system`` event; the link logs its own warning when it first hears one.
"""
from __future__ import annotations

import logging
import threading

log = logging.getLogger(__name__)

#: how often the watcher looks for newly heard foreign systems (wall seconds; the link records them)
WATCH_PERIOD_S = 0.5


def _link(service):
    loop = service.loop
    return getattr(loop, "link", None) if loop is not None else None


def link_trust(service) -> dict:
    """The link's trust report for ``/status`` (``link_trust``): foreign systems with their heartbeat
    counts, rejected timestamps, gated values; ``available: false`` and why when there is no link."""
    link = _link(service)
    if link is None or not hasattr(link, "trust_report"):
        return {"available": False, "reason": "no MAVLink link"}
    return {"available": True, **link.trust_report()}


def trust_warnings(trust: dict) -> list[dict]:
    """The operator's warnings from the link's trust report (``/status`` ``warnings``, one banner
    each on the console): more than one sender on the vehicle's own id, whose readings are mixed
    as the vehicle's (gcs_pdm.mavlink.sequence)."""
    if not trust.get("available"):
        return []
    out = []
    seq = trust.get("sequence")
    if seq and seq.get("shared"):
        # now: the readings being mixed; earlier: some of what was estimated may have been another's
        out.append({"kind": "shared_vehicle_id", "level": "critical" if seq.get("shared_now") else "warning",
                    "title": "More than one sender on the vehicle's id" + ("" if seq.get("shared_now") else " (earlier)"),
                    "text": seq["verdict"]})
    clock = trust.get("clock") or {}
    if clock.get("spoof_suspected"):
        out.append({"kind": "clock_spoofing", "level": "critical", "title": "Timestamps the vehicle did not send",
                    "text": clock.get("spoof_reason", "")})
    beats = trust.get("heartbeats") or {}
    if beats.get("suspected"):
        out.append({"kind": "heartbeat_spoofing", "level": "critical",
                    "title": "Heartbeats out of the vehicle's pattern", "text": beats.get("reason", "")})
    recording = trust.get("recording") or {}
    if recording.get("stopped"):
        # the telemetry is not affected, but nothing of this flight is being kept: /health says so
        out.append({"kind": "recording_stopped", "level": "warning", "degrades": True,
                    "title": "Recording stopped", "text": f"{recording.get('reason')}; {recording.get('dropped', 0)} "
                    "records not recorded; telemetry continues, recording resumes when the disk has room"})
    signing = trust.get("signing") or {}
    if signing and not signing.get("signed"):
        out.append({"kind": "unsigned_link", "level": "warning", "title": "MAVLink link not signed",
                    "text": ("unsigned packets are accepted" if signing.get("key") else "no signing key: anyone on the "
                             "link can send as the vehicle (spoofed heartbeats, timestamps, readings are only "
                             "detected, not prevented); run `gcs-pdm signing init` (docs/operations.md)")})
    return out


def health_reasons(warnings: list[dict]) -> list[str]:
    """The warnings that make /health degraded: the critical ones and those marked ``degrades``."""
    return [w["text"] for w in warnings if w["level"] == "critical" or w.get("degrades")]


def model_mismatch_summary(model_checks: dict[str, dict]) -> dict | None:
    """``/status``'s top-level ``model_mismatch`` from the estimate's per-pack model checks
    (``Estimate.model_mismatch``): None while every pack matches its model (or is not judged
    yet); else the packs, one sentence saying why with the refit suggestion, and that the
    predictions' spread is widened meanwhile."""
    bad = {n: c for n, c in model_checks.items() if c.get("active")}
    if not bad:
        return None
    widened = ", ".join(f"{n} ×{c.get('prediction_inflation', 1.0):.2f}" for n, c in bad.items())
    reason = ("; ".join(c.get("reason", f"pack {n} does not match its model") for n, c in bad.items())
              + f". Predictions start from a wider state spread meanwhile ({widened}). "
              + " ".join(f"Pack {n}: {c['suggestion']}." for n, c in bad.items() if c.get("suggestion")))
    return {"packs": sorted(bad), "reason": reason, "since_s": {n: c.get("since_s") for n, c in bad.items()}}


#: what each user of a parameter set does with a pack of the extended variant (docs/model.md)
PLANNER_PAPER_NOTE = ("planner uses the paper-variant values of pack {pack}: its vehicle simulator flies the paper "
                      "circuit only; the estimator, its model check and the Monte Carlo predictions use the pack's "
                      "extended values")


def model_variant_report(params) -> dict:
    """Which model variant each pack of ``params`` (a ``ParameterSet``) runs on, and where a user
    still flies an extended pack's paper values (said, never silent): for ``/status`` and the
    parameter-set activation answer."""
    packs = {n: p.model for n, p in params.packs.items()}
    return {"packs": packs,
            "notes": [PLANNER_PAPER_NOTE.format(pack=n) for n, model in packs.items() if model == "extended"]}


def foreign_system_ids(service) -> list[int]:
    """Systems other than the tracked vehicle that sent vehicle heartbeats (for ``/health``)."""
    link = _link(service)
    return sorted(f.system for f in getattr(link, "foreign_systems", ()) or ())


class ForeignSystemWatcher:
    """Publishes one ``foreign_system`` event per system the link reports as foreign (a second
    vehicle, or someone impersonating one), on its own thread, so it is told at once even when
    nobody polls ``/status`` and the vehicle itself is silent."""

    def __init__(self, service, link, period_s: float = WATCH_PERIOD_S):
        self.service = service
        self.link = link
        self.period_s = period_s
        self.reported: set[int] = set()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="foreign-systems", daemon=True)

    def start(self) -> "ForeignSystemWatcher":
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout=2.0)

    def check(self) -> list[int]:
        """Report the foreign systems not reported yet; their ids."""
        new = []
        for foreign in list(getattr(self.link, "foreign_systems", ()) or ()):
            if foreign.system in self.reported:
                continue
            self.reported.add(foreign.system)
            new.append(foreign.system)
            self.service.events.publish("foreign_system", **foreign.to_dict(),
                                        tracked_system=getattr(self.link, "target_system", None),
                                        note="sends vehicle heartbeats on our link; ignored, never tracked")
        return new

    def _run(self) -> None:
        while not self._stop.wait(self.period_s):
            try:
                self.check()
            except Exception:  # noqa: BLE001 - the watcher must outlive a bad read; the link keeps counting
                log.exception("foreign-system check failed")
