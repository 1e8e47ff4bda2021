"""A full or failing disk degrades, it does not blind (issue 34): when the live tlog cannot be
written, telemetry goes on (the link follows the vehicle), the recording stops and says so once,
and resumes when the disk has room again; write routes answer 507 with the reason."""
from __future__ import annotations

import errno
import io
import logging
import os
import sqlite3
import subprocess
import sys
from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from gcs_pdm.mavlink import connection, tlog as tlog_module
from gcs_pdm.mavlink.connection import Link, LinkConfig
from gcs_pdm.mavlink.dialect import mavlink2
from gcs_pdm.mavlink.tlog import ScanStats, TlogWriter, scan_tlog

sys.path.insert(0, str(Path(__file__).parent / "mavlink"))  # shared helpers; tests/ is not a package
from mavlink_builders import PacketFactory  # noqa: E402

TOKEN = "disk-test-token-9f3kQ2xZ"


class FakeTime:
    def __init__(self):
        self.now = 500.0

    def monotonic(self) -> float:
        return self.now

    def time(self) -> float:
        return 1.7e9 + self.now


class FailingDisk:
    """``open`` for the tlog writer: files whose writes fail with ENOSPC while ``full`` is set."""

    def __init__(self):
        self.full = False

    def __call__(self, path, mode):
        disk = self

        class File(io.FileIO):
            def write(self, data):
                if disk.full:
                    raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
                return super().write(data)

        return io.BufferedWriter(File(path, mode.replace("b", "")), buffer_size=4096)


def fly(link: Link, clock: FakeTime, vehicle: PacketFactory, seconds: float, start_ms: int) -> int:
    """The vehicle's stream at 10 Hz (position, pressure, four packs) and a 1-Hz heartbeat."""
    steps = int(seconds * 10)
    for step in range(steps):
        boot = start_ms + step * 100
        packets = [vehicle.position(boot), vehicle.pressure(boot + 5)]
        packets += [vehicle.battery(p, [4000] * 4, 1500, 2500) for p in range(4)]
        if step % 10 == 0:
            packets.append(vehicle.heartbeat())
        for packet in packets:
            msg = mavlink2.MAVLink(None).decode(bytearray(packet))
            msg._timestamp = clock.time()
            link.handle_message(msg)
        clock.now += 0.1
    return start_ms + steps * 100


def _recording_lines(caplog) -> list[str]:
    return [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING]


def run_full_disk(link, clock, disk_full, disk_free, caplog, status=None):
    """A healthy minute, then the disk fills for 30 s, then it has room again. ``status``: a callable
    giving /status, checked to follow the vehicle while the disk is full."""
    frames = []
    link.add_frame_listener(frames.append)
    vehicle = PacketFactory(1, 1, numbered=True)
    with caplog.at_level(logging.WARNING):
        boot = fly(link, clock, vehicle, 5.0, 60_000)
        written = link.tlog.records
        disk_full()
        before = len(frames)
        boot = fly(link, clock, vehicle, 30.0, boot)
        # the link followed the vehicle all along: every frame mapped, the vehicle heard
        assert len(frames) - before >= 30 * 10 * 5
        assert link.vehicle_silent_s() < 1.5
        if status is not None:  # the service's view: up, at the vehicle's latest time
            st = status()
            assert st["link"]["state"] == "up" and st["time_s"] == pytest.approx((boot - 100) / 1000, abs=0.01)
        report = link.trust_report()["recording"]
        assert report["stopped"] and report["dropped"] > 1000 and "No space left" in report["reason"]
        assert report["file"] == Path(link.tlog.path).name  # a name, not a server path
        lines = _recording_lines(caplog)
        print(f"full disk 30 s: {len(frames) - before} frames mapped, {report['dropped']} records not recorded, "
              f"{len(lines)} warning line(s): {lines}")
        assert sum("recording stopped" in line for line in lines) == 1
        assert len(lines) <= 3, lines  # one line, not one per packet (the sequence/clock may add none)
        disk_free()
        fly(link, clock, vehicle, 10.0, boot)
    report = link.trust_report()["recording"]
    assert not report["stopped"] and report["recording"]
    assert link.tlog.records > written + 50  # it resumed
    assert sum("recording resumed" in line for line in _recording_lines(caplog)) == 1
    link.tlog.close()
    # the file stays a readable tlog: the recording before and after the gap (a record cut by the
    # failure is skipped by the scanner and counted)
    stats = ScanStats()
    scanned = sum(1 for _ in scan_tlog(link.tlog.path, stats))
    assert scanned > written and stats.garbage_bytes + stats.truncated_tail_bytes < 8192


def test_a_failing_tlog_write_stops_the_recording_not_the_telemetry(tmp_path, monkeypatch, caplog):
    clock = FakeTime()
    monkeypatch.setattr(connection, "time", clock)
    disk = FailingDisk()
    link = Link(LinkConfig(url="udpin:127.0.0.1:1", heartbeat_hz=0))  # never opened: packets injected
    link.tlog = TlogWriter(tmp_path / "live.tlog", wall=clock.monotonic, opener=disk)

    def full():
        disk.full = True

    def free():
        disk.full = False

    monkeypatch.setattr(tlog_module, "RESUME_FREE_BYTES", 0)
    run_full_disk(link, clock, full, free, caplog)


def _can_mount_tmpfs(path: Path, size: str = "256k") -> bool:
    if os.geteuid() != 0:
        return False
    path.mkdir(parents=True, exist_ok=True)
    ok = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(path)],
                        capture_output=True).returncode == 0
    return ok


class _NoEstimate:
    """The telemetry thread's estimator and diagnoser, reduced to what /status's link needs."""

    pack_names = motor_names = ()

    def ready(self) -> bool:
        return False

    def consume(self, _frame) -> None:
        pass


def test_a_full_tmpfs_keeps_status_following_the_vehicle(tmp_path, monkeypatch, caplog, service):
    from gcs_pdm.service.api import create_app
    from gcs_pdm.service.telemetry_intake import TelemetryIntake

    disk_dir = tmp_path / "disk"
    if not _can_mount_tmpfs(disk_dir):
        pytest.skip("cannot mount a tmpfs here (needs root and CAP_SYS_ADMIN); the fault-injecting test covers it")
    try:
        clock = FakeTime()
        monkeypatch.setattr(connection, "time", clock)
        monkeypatch.setattr(tlog_module, "RESUME_FREE_BYTES", 64 * 1024, raising=False)
        link = Link(LinkConfig(url="udpin:127.0.0.1:1", heartbeat_hz=0))
        monkeypatch.setattr(tlog_module, "time", clock)  # the writer's retry clock
        link.tlog = TlogWriter(disk_dir / "live.tlog")
        service.attach_loop(LinkOnlyLoop(link))
        intake = TelemetryIntake(service, link, _NoEstimate(), _NoEstimate(), feed_estimator=False)
        link.add_frame_listener(intake.process)  # driven directly: the telemetry thread's work, in order
        client = TestClient(create_app(service))
        filler = disk_dir / "filler"

        def full():
            with open(filler, "wb", buffering=0) as fh:  # every byte left
                try:
                    while True:
                        fh.write(b"\0" * 4096)
                        fh.flush()
                except OSError as exc:
                    assert exc.errno == errno.ENOSPC

        def free():
            filler.unlink()

        run_full_disk(link, clock, full, free, caplog, status=lambda: client.get("/status").json())
    finally:
        subprocess.run(["umount", "-l", str(disk_dir)], check=False)


# --- the HTTP side: 507 with the reason -----------------------------------------------------------

@pytest.fixture
def service(tmp_path):
    from gcs_pdm.service.config import load_config
    from gcs_pdm.service.runtime import Service

    svc = Service(load_config(env={}, data_dir=str(tmp_path), api_token=TOKEN))
    yield svc
    svc.close()


def test_a_full_database_answers_507_with_the_reason(service, monkeypatch):
    from gcs_pdm.service.api import create_app

    def full(*_a, **_k):
        raise sqlite3.OperationalError("database or disk is full")

    monkeypatch.setattr(service.store, "add_fault", full, raising=False)
    monkeypatch.setattr(service.store, "save_parameter_set", full, raising=False)
    client = TestClient(create_app(service), raise_server_exceptions=False)
    r = client.post("/faults", json={"motor": "fwd", "magnitude": 0.3, "replan": False},
                    headers={"Authorization": f"Bearer {TOKEN}"})
    assert r.status_code == 507, r.text
    assert "full" in r.json()["detail"]
    assert client.get("/health").status_code == 200  # reads go on


def test_an_upload_onto_a_full_disk_answers_507(service, monkeypatch):
    from gcs_pdm.service import uploads
    from gcs_pdm.service.api import create_app

    real = os.fdopen

    def full_disk(fd, mode="r", *a, **k):
        fh = real(fd, mode, *a, **k)
        if "w" in mode:
            def write(_data):
                raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
            fh.write = write
        return fh

    monkeypatch.setattr(uploads.os, "fdopen", full_disk)
    client = TestClient(create_app(service), raise_server_exceptions=False)
    r = client.post("/files", files={"file": ("flight.csv", b"time_s,current_a\n0,1\n", "text/csv")},
                    headers={"Authorization": f"Bearer {TOKEN}"})
    assert r.status_code == 507, r.text
    assert "No space left on device" in r.json()["detail"]
    assert not list(service.incoming_dir.glob("*.part"))  # nothing half-written stays


class LinkOnlyLoop:
    """The part of a live loop the status report reads: its link."""

    def __init__(self, link):
        self.link = link

    def stop(self) -> None:
        pass


def test_the_service_says_once_that_the_recording_stopped_and_again_when_it_resumes(service, tmp_path,
                                                                                   monkeypatch):
    from gcs_pdm.service.api import create_app
    from gcs_pdm.service.telemetry_intake import TelemetryIntake

    clock = FakeTime()
    monkeypatch.setattr(connection, "time", clock)
    monkeypatch.setattr(tlog_module, "RESUME_FREE_BYTES", 0)
    disk = FailingDisk()
    link = Link(LinkConfig(url="udpin:127.0.0.1:1", heartbeat_hz=0))
    link.tlog = TlogWriter(tmp_path / "live.tlog", wall=clock.monotonic, opener=disk)
    service.attach_loop(LinkOnlyLoop(link))
    intake = TelemetryIntake(service, link, None, None, feed_estimator=False)
    client = TestClient(create_app(service))
    vehicle = PacketFactory(1, 1, numbered=True)
    boot = fly(link, clock, vehicle, 2.0, 10_000)
    intake.check_link()
    assert client.get("/health").json()["status"] == "ok"
    disk.full = True
    for _ in range(10):  # ten seconds of a full disk, checked once a second as the telemetry thread does
        boot = fly(link, clock, vehicle, 1.0, boot)
        intake.check_link()
    health = client.get("/health").json()
    assert health["status"] == "degraded" and any("No space left on device" in r for r in health["reasons"])
    banner = [w for w in client.get("/status").json()["warnings"] if w["kind"] == "recording_stopped"]
    assert len(banner) == 1 and banner[0]["title"] == "Recording stopped"
    disk.full = False
    for _ in range(6):
        boot = fly(link, clock, vehicle, 1.0, boot)
        intake.check_link()
    events = [(e.data["status"], e.data.get("file")) for e in service.events.since(0) if e.kind == "recording"]
    assert events == [("stopped", "live.tlog"), ("resumed", "live.tlog")]
    assert client.get("/health").json()["status"] == "ok"


def test_a_database_on_a_full_tmpfs_answers_507_and_keeps_what_it_stored(tmp_path):
    """SQLite itself meeting a full disk (not a stand-in): the write answers 507 with the reason, the
    rows stored before stay readable, and writes work again once there is room."""
    from gcs_pdm.service.api import create_app
    from gcs_pdm.service.config import load_config
    from gcs_pdm.service.runtime import Service

    disk_dir = tmp_path / "disk"
    # room for the service's whole schema (flights, packs) before the filler takes the rest
    if not _can_mount_tmpfs(disk_dir, size="2m"):
        pytest.skip("cannot mount a tmpfs here (needs root and CAP_SYS_ADMIN)")
    svc = None
    try:
        svc = Service(load_config(env={}, data_dir=str(disk_dir / "data"), api_token=TOKEN))
        client = TestClient(create_app(svc), raise_server_exceptions=False)
        auth = {"Authorization": f"Bearer {TOKEN}"}
        body = {"motor": "fwd", "magnitude": 0.2, "replan": False, "note": "n" * 1900}
        assert client.post("/faults", json=body, headers=auth).status_code == 201
        filler = disk_dir / "filler"
        with open(filler, "wb", buffering=0) as fh:
            try:
                while True:
                    fh.write(b"\0" * 4096)
            except OSError as exc:
                assert exc.errno == errno.ENOSPC
        codes = [client.post("/faults", json=body, headers=auth) for _ in range(200)]
        full = [r for r in codes if r.status_code == 507]
        assert full and all(r.status_code in (201, 507) for r in codes), {r.status_code for r in codes}
        assert "full" in full[0].json()["detail"]
        stored = client.get("/faults").json()
        assert len(stored) >= 1 and client.get("/health").status_code == 200
        filler.unlink()
        assert client.post("/faults", json=body, headers=auth).status_code == 201
    finally:
        if svc is not None:
            svc.close()
        subprocess.run(["umount", "-l", str(disk_dir)], check=False)
