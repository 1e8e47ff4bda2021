"""Replay throughput: messages per second through decoding to frames, against pymavlink's loop.

    python benchmarks/bench_replay.py [TLOG ...] [--repeat 3]

Defaults to every tlog of the shared corpus (``../shared/tlogs`` or ``$GCS_PDM_TLOG_DIR``); also
measures a generated tlog in which every message becomes a frame (the service's worst case).
Runs pinned to one CPU. Prints a line per measurement and, last, one JSON object.
"""
from __future__ import annotations

import argparse
import json
import logging
import os
import struct
import tempfile
import platform
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from gcs_pdm.mavlink.dialect import mavutil  # noqa: E402
from gcs_pdm.mavlink.mapping import FrameMapper  # noqa: E402
from gcs_pdm.mavlink.replay import replay_tlog  # noqa: E402
from gcs_pdm.mavlink.tlog import scan_tlog_bytes  # noqa: E402

TLOG_DIR = Path(os.environ.get("GCS_PDM_TLOG_DIR", REPO / ".." / "shared" / "tlogs"))


def best_of(repeat: int, fn) -> tuple[float, int]:
    best, count = float("inf"), 0
    for _ in range(repeat):
        started = time.perf_counter()
        count = fn()
        best = min(best, time.perf_counter() - started)
    return best, count


def ours_to_frames(paths) -> int:
    messages = 0
    for path in paths:
        messages += replay_tlog(path, mapper=FrameMapper()).messages
    return messages


def ours_scan_only(paths) -> int:
    return sum(sum(1 for _ in scan_tlog_bytes(Path(p).read_bytes())) for p in paths)


def pymavlink_loop(paths, match: bool) -> int:
    messages = 0
    for path in paths:
        conn = mavutil.mavlink_connection(str(path), dialect="ardupilotmega")
        while True:
            msg = conn.recv_match() if match else conn.recv_msg()
            if msg is None:
                break
            if msg.get_type() != "BAD_DATA":
                messages += 1
        conn.close()
    return messages


def synthetic_telemetry_tlog(path: Path, seconds: int = 1500) -> None:
    """Worst case for the mapping: every message is one the service turns into frames
    (10 Hz position/pressure/air data, 4 packs, 2 motors), as our vehicle would send it."""
    from gcs_pdm.mavlink.dialect import mavlink2

    mav = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
    out = bytearray()
    t_us = 1_700_000_000_000_000
    for step in range(seconds * 10):
        boot_ms = step * 100
        msgs = [mav.global_position_int_encode(boot_ms, 473977419 + step, 85455938, 500_000, 100_000, 1500, 0, 0, 9000),
                mav.scaled_pressure_encode(boot_ms, 1013.0, 0.1, 2100),
                mav.vfr_hud_encode(18.0, 17.5, 90, 55, 120.0, 0.5),
                mav.esc_telemetry_1_to_4_encode([60, 58, 0, 0], [2200] * 4, [1200, 990, 0, 0], [0] * 4,
                                                [5400, 5300, 0, 0], [0] * 4)]
        msgs += [mav.battery_status_encode(i, 0, 0, 2500, [4100] * 5 + [65535] * 5, 1500, -1, -1, -1)
                 for i in range(4)]
        if step % 10 == 0:
            msgs.append(mav.heartbeat_encode(1, 3, 0x81, 10, 4))
        for msg in msgs:
            out += struct.pack(">Q", t_us) + msg.pack(mav)
            t_us += 1000
    path.write_bytes(bytes(out))


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("tlogs", nargs="*", type=Path)
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args()
    paths = args.tlogs or sorted(TLOG_DIR.glob("*.tlog"))
    if not paths:
        print(f"no tlogs given and none in {TLOG_DIR}", file=sys.stderr)
        return 2
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {sorted(os.sched_getaffinity(0))[0]})
    logging.getLogger("gcs_pdm").setLevel(logging.ERROR)  # the corpus' bad CRCs are expected
    size = sum(Path(p).stat().st_size for p in paths)
    synthetic = Path(tempfile.mkdtemp()) / "all_mapped.tlog"
    synthetic_telemetry_tlog(synthetic)
    results = {}
    for name, fn in [("gcs_pdm_replay_to_frames", lambda: ours_to_frames(paths)),
                     ("gcs_pdm_replay_to_frames_all_mapped", lambda: ours_to_frames([synthetic])),
                     ("pymavlink_recv_msg_all_mapped", lambda: pymavlink_loop([synthetic], match=False)),
                     ("gcs_pdm_scan_only", lambda: ours_scan_only(paths)),
                     ("pymavlink_mavutil_recv_msg", lambda: pymavlink_loop(paths, match=False)),
                     ("pymavlink_mavutil_recv_match", lambda: pymavlink_loop(paths, match=True))]:
        seconds, count = best_of(args.repeat, fn)
        results[name] = {"messages": count, "seconds": round(seconds, 4), "messages_per_s": round(count / seconds)}
        print(f"{name:<30} {count:>7} messages in {seconds:7.3f} s = {count / seconds:>10,.0f} msg/s")
    ours = results["gcs_pdm_replay_to_frames"]["messages_per_s"]
    summary = {
        "benchmark": "bench_replay",
        "files": [Path(p).name for p in paths],
        "bytes": size,
        "repeat": args.repeat,
        "one_core": hasattr(os, "sched_setaffinity"),
        "python": platform.python_version(),
        "messages_per_s": ours,
        "floor_messages_per_s": 50_000,
        "speedup_vs_recv_msg": round(ours / results["pymavlink_mavutil_recv_msg"]["messages_per_s"], 2),
        "speedup_vs_recv_match": round(ours / results["pymavlink_mavutil_recv_match"]["messages_per_s"], 2),
        "all_mapped_messages_per_s": results["gcs_pdm_replay_to_frames_all_mapped"]["messages_per_s"],
        "results": results,
    }
    print(json.dumps(summary))
    return 0


if __name__ == "__main__":
    sys.exit(main())
