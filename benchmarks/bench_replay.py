"""Replay throughput: messages per second through decoding to frames, against pymavlink's loop,
and ``gcs-pdm replay FILE --json`` as a whole process on the issue-18 tlog.

    PYTHONPATH=$PWD python benchmarks/bench_replay.py [TLOG ...] [--repeat 3]

Defaults to every tlog of the shared corpus (``../shared/tlogs`` or ``$GCS_PDM_TLOG_DIR``); also
measures a generated tlog in which every message becomes a frame (the service's worst case), and a
100,000-message tlog of the simulated vehicle (four packs, ESC telemetry, typical rates; generated
once, ~40 s, cached in the temp directory) replayed with diagnosis: the whole process (start-up
included, floor 60,000 msg/s) and in-process, beside pymavlink's ``recv_msg`` loop over the same
file, with the CPU time of each stage of that replay (``replay_stages``). Every figure has wall
and CPU time (the child's ``getrusage``) and the load average.
Runs pinned to one CPU after the whole-process figure (which may use every core). Prints a line per measurement and, last, one JSON object.
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

sys.path.insert(0, str(Path(__file__).resolve().parent))
from measure import loadavg, rate, timed, timed_process  # noqa: E402

from gcs_pdm.mavlink.dialect import mavutil  # noqa: E402
from gcs_pdm.mavlink.mapping import FrameMapper  # noqa: E402
from gcs_pdm.mavlink.replay import replay_tlog  # noqa: E402
from gcs_pdm.mavlink.tlog import scan_tlog_bytes, scanned_tlog  # noqa: E402

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


def ours_diagnosed(paths) -> int:
    from gcs_pdm.diagnosis.pipeline import DiagnosisPipeline

    return sum(replay_tlog(p, mapper=FrameMapper(), frame_consumer=DiagnosisPipeline()).messages for p in paths)


def replay_stages(path: Path) -> dict:
    """CPU seconds of each stage of ``gcs-pdm replay FILE --json`` in this process (after the
    imports): the one scan of the log (shared since issue 18's replay work), the provisional
    description (decoding its messages from that scan, deriving), the frame mapping, the replay
    with diagnosis, and within the latter the pack-health checks and the trace's cut-off Monte Carlo
    (wrapped timers; the pack-health fits and the trace's flights, which the command runs on other
    threads, run on the calling thread here)."""
    import gcs_pdm.diagnosis.pack_health as pack_health
    import gcs_pdm.estimation.prediction as prediction
    from gcs_pdm.replay.vehicle import TracedPipeline, replay_vehicle
    from gcs_pdm.mavlink.vehicle_mapping import envelope, frame_mapping

    spent = {"pack_health_check": 0.0, "trace_monte_carlo": 0.0}

    def timing(fn, key):
        def wrapped(*args, **kwargs):
            c0 = time.process_time()
            try:
                return fn(*args, **kwargs)
            finally:
                spent[key] += time.process_time() - c0
        return wrapped

    check, draw, fly, threads = (pack_health.PackHealthMonitor.check, prediction.draw_held_current,
                                 prediction.HeldCurrentSamples.fly, pack_health.thread_map)
    pack_health.PackHealthMonitor.check = timing(check, "pack_health_check")
    prediction.draw_held_current = timing(draw, "trace_monte_carlo")
    prediction.HeldCurrentSamples.fly = timing(fly, "trace_monte_carlo")
    pack_health.thread_map = lambda fn, items: [fn(i) for i in items]
    try:
        c0 = time.process_time()
        scanned_tlog(path)  # kept for the provisional description and the replay, as in the command
        c1 = time.process_time()
        desc, about = replay_vehicle(path, None)
        c2 = time.process_time()
        replay_tlog(path, mapper=FrameMapper(frame_mapping(desc), envelope=envelope(desc)))
        c3 = time.process_time()
        scanned_tlog(path)  # the replay took the scan: keep it again for the diagnosed replay
        consumer = TracedPipeline(desc, about, background=False)
        replay_tlog(path, mapper=FrameMapper(frame_mapping(desc), envelope=envelope(desc)), frame_consumer=consumer)
        json.dumps(consumer.report())
        c4 = time.process_time()
    finally:
        pack_health.PackHealthMonitor.check, prediction.draw_held_current = check, draw
        prediction.HeldCurrentSamples.fly = fly
        pack_health.thread_map = threads
    out = {"scan_cpu_s": c1 - c0, "provisional_description_cpu_s": c2 - c1, "frame_mapping_cpu_s": c3 - c2,
           "replay_diagnosed_cpu_s": c4 - c3, **{f"{k}_cpu_s": v for k, v in spent.items()}}
    out["scan_and_mapping_cpu_s"] = out["scan_cpu_s"] + out["frame_mapping_cpu_s"]
    out["pipeline_rest_cpu_s"] = out["replay_diagnosed_cpu_s"] - out["frame_mapping_cpu_s"] - sum(spent.values())
    return {k: round(v, 3) for k, v in out.items()} | {"loadavg_1min": loadavg()}


def whole_process_replay(path: Path, repeat: int) -> dict:
    """``gcs-pdm replay FILE --json`` in a child process (our PYTHONPATH), start-up included, on
    every core this process may use (the command overlaps work on a second thread; issue 18
    accepts both cores): wall is what a user waits, CPU what it costs."""
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")])}
    t = timed_process([sys.executable, "-m", "gcs_pdm.cli", "replay", str(path), "--json"], repeat, env)
    summary = json.loads(t["stdout"])
    n = summary["messages"]
    return {"file": path.name, "messages": n, "frames": summary["frames"], "faults": len(summary["faults"]),
            "cpu_per_s": round(n / t["cpu_s"]), "wall_per_s": round(n / t["wall_s"]),
            "cpu_s": round(t["cpu_s"], 3), "wall_s": round(t["wall_s"], 3), "loadavg_1min": t["loadavg_1min"],
            "in_process_elapsed_s": summary["elapsed_s"],
            "cores": len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()}


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


#: the project's typical stream (the simulated vehicle's defaults: 2 Hz BATTERY_STATUS per pack,
#: 2 Hz ESC telemetry) with position and air data at 10 Hz, as a ground station asks for them
TYPICAL_RATES_OVERRIDE = {"GLOBAL_POSITION_INT": 10.0, "VFR_HUD": 10.0}
TYPICAL_MESSAGES = 100_000


def typical_telemetry_tlog(path: Path, messages: int = TYPICAL_MESSAGES) -> Path:
    """A ``messages``-record tlog of the simulated vehicle (four packs, two ESCs) flying a long
    mission at typical rates: the figure of issue 18. Deterministic; cached at ``path``."""
    if path.exists():
        return path
    import numpy as np

    sys.path.insert(0, str(REPO / "fixtures"))
    from make_fixtures import route
    from gcs_pdm.sim.model import SimConfig
    from gcs_pdm.sim.record import fly
    from gcs_pdm.sim.routes import mission_from_enu
    from gcs_pdm.sim.telemetry import DEFAULT_RATES, TelemetryConfig

    points = route(np.random.default_rng(18), 80.0, 20.0, speed_changes=True)
    mission = mission_from_enu(points, takeoff_alt_m=float(points[0][2]))
    cfg = SimConfig(seed=18, ground_temp_c=20.0, cruise_airspeed_mps=20.0, initial_soc=1.0, mission=tuple(mission))
    full = path.with_suffix(".full.tlog")
    fly(cfg, TelemetryConfig(rates_hz={**DEFAULT_RATES, **TYPICAL_RATES_OVERRIDE}), full)
    data = full.read_bytes()
    ends = [end for *_, end in scan_tlog_bytes(data)]
    if len(ends) < messages:
        raise RuntimeError(f"the simulated flight gave only {len(ends)} messages, not {messages}")
    path.write_bytes(data[:ends[messages - 1]])
    full.unlink()
    return path


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("tlogs", nargs="*", type=Path)
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args()
    paths = args.tlogs or sorted(TLOG_DIR.glob("*.tlog"))
    if not paths:
        print(f"no tlogs given and none in {TLOG_DIR}", file=sys.stderr)
        return 2
    logging.getLogger("gcs_pdm").setLevel(logging.ERROR)  # the corpus' bad CRCs are expected
    size = sum(Path(p).stat().st_size for p in paths)
    synthetic = Path(tempfile.mkdtemp()) / "all_mapped.tlog"
    synthetic_telemetry_tlog(synthetic)
    results = {}
    typical = typical_telemetry_tlog(Path(tempfile.gettempdir()) / "gcs_pdm_bench_typical_100k_v1.tlog")
    whole = whole_process_replay(typical, args.repeat)  # before the pinning: the command may use both cores
    print(f"{'gcs_pdm_replay_json_whole_process':<30} {whole['messages']:>7} messages: "
          f"cpu {whole['cpu_per_s']:>8,} msg/s, wall {whole['wall_per_s']:>8,} msg/s on {whole['cores']} cores "
          f"(load {whole['loadavg_1min']})")
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {sorted(os.sched_getaffinity(0))[0]})
    stages = replay_stages(typical)
    print("stages (CPU s, in-process): " + ", ".join(f"{k.removesuffix('_cpu_s')} {v}" for k, v in stages.items()))
    for name, fn in [("gcs_pdm_replay_diagnosed_in_process", lambda: ours_diagnosed([typical])),
                     ("pymavlink_recv_msg_typical", lambda: pymavlink_loop([typical], match=False))]:
        count = fn()
        t = timed(fn, args.repeat)
        results[name] = {"messages": count, **rate(count, t, "messages_per_s")}
        print(f"{name:<36} cpu {results[name]['cpu_messages_per_s']:>8,} msg/s, wall "
              f"{results[name]['wall_messages_per_s']:>8,} msg/s")
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
        "replay_json_whole_process": {**{k: v for k, v in whole.items()}, "floor_messages_per_s": 60_000,
                                      "reached_cpu": whole["cpu_per_s"] >= 60_000,
                                      "reached_wall": whole["wall_per_s"] >= 60_000},
        "replay_stages": stages,
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
