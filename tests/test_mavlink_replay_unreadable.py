"""`gcs-pdm replay` says what it could not diagnose and why, and fails when nothing was read."""
from __future__ import annotations

import json
import os
import subprocess
import sys
import zlib
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).parent / "mavlink"))  # shared helpers; tests/ is not a package
from mavlink_builders import PacketFactory, tlog_record  # noqa: E402

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def _png() -> bytes:
    def chunk(kind: bytes, data: bytes) -> bytes:
        return len(data).to_bytes(4, "big") + kind + data + zlib.crc32(kind + data).to_bytes(4, "big")
    rows = b"".join(b"\0" + bytes(range(48)) for _ in range(16))
    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", (16).to_bytes(4, "big") * 2 + b"\x08\x02\0\0\0")
            + chunk(b"IDAT", zlib.compress(rows)) + chunk(b"IEND", b"")) * 50


def _replay(path: Path, *extra: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "gcs_pdm.cli", "replay", str(path), "--no-diagnose", *extra],
                          capture_output=True, text=True, cwd=REPO, timeout=60)


@pytest.mark.slow
def test_png_and_empty_files_are_not_read_and_fail(tmp_path):
    png = tmp_path / "photo.tlog"
    png.write_bytes(_png())
    empty = tmp_path / "empty.tlog"
    empty.write_bytes(b"")
    for path, why in ((png, "no valid MAVLink packet"), (empty, "the file is empty")):
        out = _replay(path)
        assert out.returncode == 2 and why in out.stderr and "Traceback" not in out.stderr, out
        out = _replay(path, "--json")
        summary = json.loads(out.stdout.strip().splitlines()[-1])
        assert out.returncode == 2 and summary["readable"] is False
        assert why in summary["not_diagnosed"][0]


def test_a_log_without_the_needed_streams_says_what_was_not_diagnosed(tmp_path):
    v = PacketFactory()
    packets = [v.heartbeat()] + [v.position(1000 + 100 * k) for k in range(20)] + [v.hud()]
    path = tmp_path / "position_only.tlog"
    path.write_bytes(b"".join(tlog_record(1_700_000_000_000_000 + 100_000 * k, p) for k, p in enumerate(packets)))
    out = _replay(path, "--json")
    summary = json.loads(out.stdout.strip().splitlines()[-1])
    assert out.returncode == 1 and summary["readable"] is True
    joined = " | ".join(summary["not_diagnosed"])
    assert "no BATTERY_STATUS" in joined and "no ESC_TELEMETRY_1_TO_4" in joined
    text = _replay(path)
    assert text.returncode == 1 and "not diagnosed: battery packs" in text.stdout
    assert "nothing could be diagnosed" in text.stdout


def test_a_damaged_tlog_timestamp_beyond_any_date_is_no_crash(tmp_path):
    # the record's 8-byte stamp is outside the packet's CRC: damage there leaves a valid packet
    # whose time no calendar holds (2**63 µs ≈ year 294,247); the replay says the start is unknown
    v = PacketFactory()
    packets = [v.heartbeat()] + [v.position(1000 + 100 * k) for k in range(20)]
    stamps = [2 ** 63] + [1_700_000_000_000_000 + 100_000 * k for k in range(1, len(packets))]
    path = tmp_path / "bad_stamp.tlog"
    path.write_bytes(b"".join(tlog_record(s, p) for s, p in zip(stamps, packets)))
    from gcs_pdm.mavlink.replay import replay_tlog

    summary = replay_tlog(path)
    assert summary.messages == len(packets) and summary.tlog_start_utc is None
    out = _replay(path, "--json")
    assert "Traceback" not in out.stderr, out.stderr
    assert json.loads(out.stdout.strip().splitlines()[-1])["tlog_start_utc"] is None
