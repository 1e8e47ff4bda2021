"""tlog scanning and replay: the shared corpus of real logs, damaged files, the replay CLI."""
from __future__ import annotations

import json
import random
import subprocess
import sys
from collections import Counter
from pathlib import Path

import pytest

from gcs_pdm.mavlink.dialect import MESSAGE_CLASSES, mavutil
from gcs_pdm.mavlink.replay import replay_tlog
from gcs_pdm.mavlink.tlog import ScanStats, TlogWriter, scan_tlog, scan_tlog_bytes, tlog_message_dicts

sys.path.insert(0, str(Path(__file__).parent / "mavlink"))  # shared helpers; tests/ is not a package
from mavlink_builders import PacketFactory, tlog_record  # noqa: E402
from tlog_corpus import TLOG_DIR, needs_corpus  # noqa: E402

REPO = Path(__file__).parents[1]

# Per file: valid packets, bad-CRC packets, frames by kind. Packet counts equal pymavlink's reader
# (README of the corpus and test_counts_match_pymavlink below); frame counts are what the default
# mapping makes of them.
EXPECTED = {
    "MarcusUWA_EAICS_flight.tlog": (8164, 0, {"airdata": 264, "ambient": 301, "mission_progress": 294,
                                              "position": 277, "status": 87, "statustext": 3, "wind": 258}),
    "UAVLogViewer_vtol.tlog": (23894, 0, {"airdata": 874, "ambient": 790, "mission_progress": 796,
                                          "position": 803, "status": 199, "statustext": 10, "wind": 806}),
    "ahmadkhanfar_TLOG_test.tlog": (10277, 0, {"airdata": 534, "ambient": 268, "mission_progress": 268,
                                               "motor": 526, "pack": 268, "position": 268, "status": 140,
                                               "statustext": 35, "wind": 193}),
    "clydemcqueen_pymavlink_bug_2023-04-18.tlog": (50136, 1967, {"airdata": 3116, "ambient": 627,
                                                                 "mission_progress": 627, "pack": 938,
                                                                 "position": 938, "status": 314,
                                                                 "statustext": 28}),
    "jschall_magfit_scaling_test.tlog": (2632, 0, {"airdata": 140, "ambient": 140, "mission_progress": 140,
                                                   "position": 140, "status": 48, "statustext": 5}),
}

def corpus_files() -> list[Path]:
    return sorted(TLOG_DIR.glob("*.tlog")) if TLOG_DIR.is_dir() else []


@needs_corpus
def test_corpus_is_complete():
    assert {p.name for p in corpus_files()} >= set(EXPECTED)


@needs_corpus
@pytest.mark.parametrize("name", sorted(EXPECTED))
def test_replay_corpus_file_to_the_end(name):
    records, bad_crc, frames = EXPECTED[name]
    collected = []
    summary = replay_tlog(TLOG_DIR / name, frame_consumer=collected.append)
    assert summary.messages == records
    assert summary.scan["bad_crc"] == bad_crc
    assert summary.scan["truncated_tail_bytes"] == 0 and summary.scan["garbage_bytes"] == 0
    assert summary.mapping["frames_by_kind"] == frames
    assert len(collected) == sum(frames.values())
    assert summary.vehicle["system"] == 1 and summary.vehicle["component"] == 1
    # Frame times run forwards within one kind and key, but for rare glitches in the vehicle's
    # own time_boot_ms (the SITL log steps back 1.2 s once), which are shorter than a reboot.
    last: dict = {}
    backsteps = 0
    for frame in collected:
        key = (type(frame), getattr(frame, "pack", None), getattr(frame, "motor", None))
        previous = last.get(key, float("-inf"))
        if frame.time_s < previous:
            backsteps += 1
            assert previous - frame.time_s < 2.0
        last[key] = frame.time_s
    assert backsteps <= 3
    # No sentinel leaks into the frames.
    for frame in collected:
        for value in (getattr(frame, "temperature_c", None), getattr(frame, "current_a", None)):
            assert value is None or -100 < value < 400


@pytest.mark.slow
@needs_corpus
def test_counts_match_pymavlink():
    for path in corpus_files():
        ours = Counter(msgid for _, msgid, *_ in scan_tlog(path))
        conn = mavutil.mavlink_connection(str(path), dialect="ardupilotmega")
        theirs, bad = Counter(), 0
        while (msg := conn.recv_msg()) is not None:
            if msg.get_type() == "BAD_DATA":
                bad += 1
            else:
                theirs[msg.get_msgId()] += 1
        conn.close()
        assert ours == theirs, path.name
        if path.name in EXPECTED:
            assert bad == EXPECTED[path.name][1]


def _pymavlink_dicts(path: Path, names: list[str]) -> list[tuple[str, dict]]:
    conn = mavutil.mavlink_connection(str(path), dialect="ardupilotmega", robust_parsing=True)
    out = []
    while (msg := conn.recv_match(type=names, blocking=False)) is not None:
        fields = msg.to_dict()
        fields.pop("mavpackettype")
        out.append((msg.get_type(), fields))
    conn.close()
    return out


STOCK_TLOG = REPO.parent / "shared" / "logs" / "arduplane_sitl_stock.tlog"


@pytest.mark.parametrize("path", [REPO / "fixtures" / "flights" / "fault_01.tlog",
                                  pytest.param(STOCK_TLOG, marks=pytest.mark.skipif(
                                      not STOCK_TLOG.is_file(),
                                      reason="needs ../shared/logs (the stock ArduPlane SITL session)"))],
                         ids=lambda p: p.name)
def test_message_dicts_are_pymavlinks(path):
    """The fast decoder of the messages the provisional description reads gives pymavlink's
    ``to_dict()`` field for field (arrays as lists, text up to its NUL), message for message."""
    names = ["HEARTBEAT", "BATTERY_STATUS", "PARAM_VALUE", "ESC_TELEMETRY_1_TO_4", "SYS_STATUS",
             "STATUSTEXT", "GLOBAL_POSITION_INT"]
    ours = list(tlog_message_dicts(path, names))
    theirs = _pymavlink_dicts(path, names)
    assert len(ours) == len(theirs) > 100
    assert {n for n, _ in ours} >= {"HEARTBEAT", "BATTERY_STATUS", "STATUSTEXT"}
    assert repr(ours) == repr(theirs)  # repr: NaN fields compare equal


@needs_corpus
def test_corpus_known_content():
    """Spot checks against what the corpus README says the files hold."""
    vtol = replay_tlog(TLOG_DIR / "UAVLogViewer_vtol.tlog")
    assert len(vtol.messages_by_type) == 41 and "BATTERY_STATUS" not in vtol.messages_by_type
    assert vtol.scan["mavlink2"] == 0
    mixed = replay_tlog(TLOG_DIR / "ahmadkhanfar_TLOG_test.tlog")
    assert mixed.messages_by_type["BATTERY_STATUS"] == 268 and mixed.messages_by_type["ESC_TELEMETRY_1_TO_4"] == 263
    assert mixed.scan["mavlink1"] > 0 and mixed.scan["mavlink2"] > 0
    sub = replay_tlog(TLOG_DIR / "clydemcqueen_pymavlink_bug_2023-04-18.tlog")
    assert sub.messages + sub.scan["bad_crc"] == 52103
    assert sub.mapping["other_source"] > 0  # several components on one link


@needs_corpus
def test_randomly_damaged_corpus_never_crashes():
    rng = random.Random(4)
    for path in corpus_files():
        data = bytearray(path.read_bytes())
        for _ in range(len(data) // 500):  # ~0.2 % of the bytes overwritten
            data[rng.randrange(len(data))] = rng.randrange(256)
        cut = len(data) - rng.randrange(1, 40)
        stats = ScanStats()
        good = sum(1 for _ in scan_tlog_bytes(bytes(data[:cut]), stats))
        clean = EXPECTED.get(path.name, (None,))[0]
        assert good == stats.records
        if clean is not None:
            assert 0.5 * clean < good <= clean
        assert stats.bad_crc + stats.garbage_bytes + stats.truncated_tail_bytes > 0


def synthetic_tlog() -> tuple[list[bytes], bytes]:
    v2, v1 = PacketFactory(), PacketFactory(mavlink1=True)
    packets = [v2.heartbeat(), v1.heartbeat(), v2.position(1000), v1.pressure(1100), v2.battery(0, [4000] * 5, 1234, 2500),
               v2.hud(), v2.position(1200)]
    records = [tlog_record(1_700_000_000_000_000 + 1000 * i, p) for i, p in enumerate(packets)]
    return packets, b"".join(records)


def test_damage_is_skipped_and_counted():
    packets, _ = synthetic_tlog()
    records = [tlog_record(1_700_000_000_000_000 + 1000 * i, p) for i, p in enumerate(packets)]
    garbage = b"\x00\x13 not mavlink \xfd\x09\x00"  # includes a fake magic byte
    bad = bytearray(records[2])
    bad[-1] ^= 0xFF  # corrupt the CRC of the first GLOBAL_POSITION_INT
    truncated_tail = records[6][:-5]
    data = b"".join([records[0], garbage, records[1], bytes(bad), *records[3:6], truncated_tail])
    stats = ScanStats()
    got = list(scan_tlog_bytes(data, stats))
    assert stats.records == len(got) == 5
    assert stats.bad_crc == 1
    assert stats.garbage_bytes == len(garbage)
    assert stats.truncated_tail_bytes == len(truncated_tail)
    assert stats.mavlink1 == 2 and stats.mavlink2 == 3


def test_unknown_message_id_is_counted(tmp_path):
    v2 = PacketFactory()
    hb = bytearray(v2.heartbeat())
    hb[7:10] = (0x7FF0).to_bytes(3, "little")  # msgid outside the dialect
    data = tlog_record(1, bytes(hb)) + tlog_record(2, v2.heartbeat())
    stats = ScanStats()
    assert len(list(scan_tlog_bytes(data, stats))) == 1
    assert stats.unknown_msgid == 1


def test_a_file_is_scanned_once_for_the_description_and_the_replay(tmp_path, monkeypatch):
    """``gcs-pdm replay`` reads a log twice (provisional description, replay): the second reader gets
    the first one's scan, the same records and counts as a fresh scan; a changed file is scanned
    again; a file above the size limit is streamed, with the same summary."""
    import gcs_pdm.mavlink.tlog as tlog
    from gcs_pdm.mavlink.wire import layout

    packets, _ = synthetic_tlog()
    v2 = PacketFactory()
    bad = bytearray(v2.heartbeat())
    bad[-1] ^= 0xFF
    data = b"".join(tlog_record(1_000_000 + i, p) for i, p in enumerate(packets)) + tlog_record(9, bytes(bad)) + b"\x00\x01"
    path = tmp_path / "once.tlog"
    path.write_bytes(data)
    stats = ScanStats()
    fresh = [(ts, m, s, c, bytes(p), a, b) for ts, m, s, c, p, a, b in scan_tlog_bytes(data, stats)]
    scans = []
    monkeypatch.setattr(tlog, "_scan_records", lambda *a, f=tlog._scan_records, **k: scans.append(1) or f(*a, **k))
    first = tlog.scanned_tlog(path)
    assert [(ts, m, s, c, bytes(p), a, b) for ts, m, s, c, p, a, b in first.records()] == fresh
    assert first.stats == stats and stats.garbage_bytes > 0
    names = ["HEARTBEAT", "GLOBAL_POSITION_INT"]
    want = [(MESSAGE_CLASSES[m].msgname, layout(m).as_dict(p)) for _, m, _, _, p, *_ in fresh
            if MESSAGE_CLASSES[m].msgname in names]
    assert list(tlog_message_dicts(path, names)) == want != []
    summary = replay_tlog(path).to_dict()
    assert len(scans) == 1 and tlog._last_scan is None  # the replay took the scan: nothing is kept
    assert tlog.scanned_tlog(path) is not first and len(scans) == 2
    path.write_bytes(data + tlog_record(10, v2.heartbeat()))
    assert len(tlog.scanned_tlog(path)) == len(first) + 1 and len(scans) == 3
    path.write_bytes(data)
    monkeypatch.setattr(tlog, "SCAN_CACHE_MAX_BYTES", len(data) - 1)
    assert tlog.scanned_tlog(path) is None and tlog.take_kept_scan(path) is None
    streamed = replay_tlog(path).to_dict()
    for s in (summary, streamed):
        s.pop("elapsed_s"), s.pop("messages_per_s")
    assert streamed == summary and summary["scan"]["records"] == len(fresh)


def _signed(packet: bytes) -> bytes:
    """A MAVLink 2 packet marked signed (incompat flag, CRC redone, 13 signature bytes appended)."""
    from fastcrc.crc16 import mcrf4xx

    from gcs_pdm.mavlink.dialect import CRC_EXTRA

    body = bytearray(packet[:-2])
    body[2] |= 0x01
    msgid = body[7] | (body[8] << 8) | (body[9] << 16)
    crc = mcrf4xx(bytes((CRC_EXTRA[msgid],)), mcrf4xx(bytes(body[1:])))
    return bytes(body) + crc.to_bytes(2, "little") + bytes(range(13))


@pytest.mark.parametrize("damage", [None, "bad_crc", "unknown_msgid", "garbage", "truncated", "short_tail"])
def test_scan_of_a_whole_file_is_the_sequential_scan(tmp_path, damage):
    """The scan a command keeps computes the headers and CRCs of all records at once when nothing
    is damaged, and falls back to the sequential scanner otherwise: both give the records and counts
    of :func:`scan_tlog_bytes` (MAVLink 1 and 2, signed packets, zero-truncated payloads)."""
    import gcs_pdm.mavlink.tlog as tlog

    v2, v1 = PacketFactory(), PacketFactory(mavlink1=True)
    packets = [v2.heartbeat(), v1.heartbeat(), _signed(v2.position(1000)), v1.pressure(1100),
               v2.battery(0, [4000] * 5, 1234, 2500), _signed(v2.hud()), v2.position(1200), v1.battery(1, [0], 0, 0)]
    packets *= 40
    if damage == "bad_crc":
        packets[17] = packets[17][:-3] + bytes([packets[17][-3] ^ 0x55]) + packets[17][-2:]
    elif damage == "unknown_msgid":
        bad = bytearray(v2.heartbeat())
        bad[7:10] = (0x7FF0).to_bytes(3, "little")
        packets[30] = bytes(bad)
    data = b"".join(tlog_record(1_700_000_000_000_000 + 1000 * i, p) for i, p in enumerate(packets))
    if damage == "garbage":
        data = data[:500] + b"\x07\xfd\x03" + data[500:]
    elif damage == "truncated":
        data = data[:-5]
    elif damage == "short_tail":
        data += b"\x00" * 6
    stats = ScanStats()
    want = [(ts, m, s, c, bytes(p), a, b) for ts, m, s, c, p, a, b in scan_tlog_bytes(data, stats)]
    path = tmp_path / "whole.tlog"
    path.write_bytes(data)
    assert (tlog._scan_flawless(data) is None) == (damage is not None)
    got = tlog.scanned_tlog(path)
    assert [(ts, m, s, c, bytes(p), a, b) for ts, m, s, c, p, a, b in got.records()] == want
    assert got.stats == stats and stats.signed == 80
    heartbeats = {MESSAGE_CLASSES[m].msgname: m for _, m, *_ in want}["HEARTBEAT"]
    assert [r[:4] for r in got.records({heartbeats})] == [r[:4] for r in want if r[1] == heartbeats]
    tlog.take_kept_scan(path)


def test_writer_and_scanner_round_trip(tmp_path):
    packets, _ = synthetic_tlog()
    path = tmp_path / "w.tlog"
    with TlogWriter(path) as writer:
        for i, p in enumerate(packets):
            writer.write(p, 1_700_000_000.0 + i * 0.25)
    got = list(scan_tlog(path))
    assert [ts for ts, *_ in got] == [1_700_000_000_000_000 + i * 250_000 for i in range(len(packets))]
    assert [MESSAGE_CLASSES[m].msgname for _, m, *_ in got][:3] == ["HEARTBEAT", "HEARTBEAT", "GLOBAL_POSITION_INT"]


def test_replay_cli_json(tmp_path):
    _, data = synthetic_tlog()
    path = tmp_path / "s.tlog"
    path.write_bytes(data + b"\xfd\x1c")  # truncated tail
    out = subprocess.run([sys.executable, "-m", "gcs_pdm.cli", "replay", str(path), "--json", "--no-diagnose"],
                         capture_output=True, text=True, cwd=REPO, timeout=60)
    assert out.returncode == 0, out.stderr
    summary = json.loads(out.stdout.strip().splitlines()[-1])
    assert summary["messages"] == 7
    assert summary["messages_by_type"] == {"GLOBAL_POSITION_INT": 2, "HEARTBEAT": 2, "BATTERY_STATUS": 1,
                                           "SCALED_PRESSURE": 1, "VFR_HUD": 1}
    assert summary["frames_by_kind"] == {"airdata": 1, "ambient": 1, "pack": 1, "position": 2, "status": 2}
    assert summary["skipped"]["truncated_tail_bytes"] == 2
    assert summary["faults"] == [] and summary["consumer"] is None
    assert summary["frame_time_span_s"] == pytest.approx([0.998, 1.2])  # heartbeats back-dated 2 ms
    # By default the diagnoser consumes the frames; its faults land in the same summary.
    out = subprocess.run([sys.executable, "-m", "gcs_pdm.cli", "replay", str(path), "--json"],
                         capture_output=True, text=True, cwd=REPO, timeout=60)
    assert out.returncode == 0, out.stderr
    diagnosed = json.loads(out.stdout.strip().splitlines()[-1])
    assert diagnosed["messages"] == 7 and isinstance(diagnosed["faults"], list)


def test_replay_resends_to_udp_and_paces(tmp_path):
    import socket
    import time

    _, data = synthetic_tlog()
    path = tmp_path / "s.tlog"
    path.write_bytes(data)
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as rx:
        rx.bind(("127.0.0.1", 0))
        rx.settimeout(2)
        started = time.monotonic()
        replay_tlog(path, speed=1.0, udp_target=f"127.0.0.1:{rx.getsockname()[1]}")
        elapsed = time.monotonic() - started
        received = [rx.recv(1024) for _ in range(7)]
    packets, _ = synthetic_tlog()
    assert received == packets
    assert elapsed >= 0.006 - 0.001  # 6 ms of tlog time at x1


def test_consumer_report_hook_reaches_summary(tmp_path):
    _, data = synthetic_tlog()
    path = tmp_path / "s.tlog"
    path.write_bytes(data)

    class Diagnoser:
        def __init__(self):
            self.frames = 0

        def __call__(self, frame):
            self.frames += 1

        def report(self):
            return {"faults": [{"time_s": 1.2, "type": "motor", "magnitude": 0.3}], "frames": self.frames}

    summary = replay_tlog(path, frame_consumer=Diagnoser()).to_dict()
    assert summary["faults"] == [{"time_s": 1.2, "type": "motor", "magnitude": 0.3}]
    assert summary["consumer"]["frames"] == 7


def test_signed_counts_the_signed_packets_handed_out_not_damaged_ones():
    """``ScanStats.signed`` counts CRC-valid signed packets, as the whole-file scan does: a damaged
    packet whose flag byte says signed is counted as bad CRC only."""
    v2 = PacketFactory()
    good, damaged = _signed(v2.hud()), bytearray(_signed(v2.hud()))
    damaged[-14] ^= 0x55  # a CRC byte (13 signature bytes follow it)
    data = b"".join(tlog_record(1_700_000_000_000_000 + 1000 * i, p)
                    for i, p in enumerate([v2.heartbeat(), good, bytes(damaged), v2.heartbeat()]))
    stats = ScanStats()
    records = list(scan_tlog_bytes(data, stats))
    assert len(records) == 3 and stats.bad_crc == 1 and stats.signed == 1


def test_a_paced_replay_does_not_wait_for_a_damaged_stamp(tmp_path):
    """A record whose 8-byte stamp is damaged (outside the packet's CRC) far ahead of its
    neighbours is not waited for, nor is the way back from it: the paced replay of a 6 ms log with
    one stamp ~9 hours ahead still takes milliseconds, and the stamps around it are paced."""
    import threading
    import time

    packets, _ = synthetic_tlog()
    stamps = [1_700_000_000_000_000 + 1000 * i for i in range(len(packets))]
    stamps[3] += 32_000 * 1_000_000  # ≈ 8.9 h ahead
    path = tmp_path / "stamp.tlog"
    path.write_bytes(b"".join(tlog_record(s, p) for s, p in zip(stamps, packets)))
    done = threading.Event()
    out = {}

    def run():
        started = time.monotonic()
        out["summary"] = replay_tlog(path, speed=1.0)
        out["elapsed"] = time.monotonic() - started
        done.set()

    threading.Thread(target=run, daemon=True).start()
    assert done.wait(10.0), "the paced replay waited for the damaged stamp"
    assert out["summary"].messages == len(packets) and out["elapsed"] >= 0.003 - 0.001
