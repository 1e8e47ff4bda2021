"""Reading a 100 MB ArduPilot DataFlash log into flight tables: the bulk reader vs pymavlink's DFReader.

    python benchmarks/bench_logs.py [--size-mb 100] [--source LOG.bin] [--skip-dfreader]

The log is synthesised in a temporary directory from the shared stock ArduPlane log
(``../shared/logs/arduplane_sitl_stock.bin``): copies one after the other, each copy's ``TimeUS``
shifted past the previous one so time keeps increasing, as in one long flight. Both readers
produce the battery and motor flight tables the fitter takes (BAT per instance, ESC, BARO as
ambient); the figures are wall-clock seconds of one run each (the first run of ours includes
numba's compile or cache load, reported apart). Floor: ours under 10 s. Last line: one JSON object.
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from gcs_pdm.logs.dataflash import read_dataflash  # noqa: E402
from gcs_pdm.logs.reader import read_log  # noqa: E402
from gcs_pdm.logs.series import battery_flights, motor_flight  # noqa: E402

SOURCE = REPO / ".." / "shared" / "logs" / "arduplane_sitl_stock.bin"
FLOOR_S = 10.0


def synthesise(source: Path, size_mb: float, out: Path) -> Path:
    """Copies of ``source`` with TimeUS shifted so that time increases across copies."""
    log = read_dataflash(source)
    data = log.data.copy()
    timed = np.zeros(256, bool)
    for fmt in log.formats.values():
        timed[fmt.type] = fmt.format[:1] == "Q" and fmt.columns[:1] == ("TimeUS",)
    at = log.starts[timed[log.types]]
    idx = at[:, None] + np.arange(3, 11)
    base = data[idx].reshape(-1).view("<u8").copy()
    span = int(base.max() - base.min()) + 1_000_000
    copies = max(1, int(np.ceil(size_mb * 1e6 / data.size)))
    with out.open("wb") as fh:
        for k in range(copies):
            data[idx] = (base + np.uint64(k * span)).view(np.uint8).reshape(-1, 8)
            fh.write(data.tobytes())
    return out


def ours(path: Path) -> dict:
    series = read_log(path)
    flights = battery_flights(series) + [motor_flight(series)]
    return {"rows": {f.name: len(f) for f in flights}}


def dfreader(path: Path) -> dict:
    """The same tables through DFReader's per-message loop."""
    from pymavlink import DFReader

    reader = DFReader.DFReader_binary(str(path))
    bat, esc, baro = [], [], []
    while (m := reader.recv_match(type=["BAT", "ESC", "BARO"])) is not None:
        kind = m.get_type()
        if kind == "BAT":
            bat.append((m.TimeUS, m.Inst, m.Volt, m.Curr, m.Temp))
        elif kind == "ESC":
            esc.append((m.TimeUS, m.Instance, m.RPM, m.Curr, m.Temp))
        elif m.I == 0:
            baro.append((m.TimeUS, m.Temp))
    bat, esc, baro = np.array(bat), np.array(esc), np.array(baro)
    rows = {}
    for inst in np.unique(bat[:, 1]):
        b = bat[bat[:, 1] == inst]
        amb = np.interp(b[:, 0], baro[:, 0], baro[:, 1])
        rows[f"bat{int(inst)}"] = int(np.column_stack([b[:, 0], b[:, 2], b[:, 3], b[:, 4], amb]).shape[0])
    rows["esc"] = int(esc.shape[0])
    return {"rows": rows}


def timed(fn, *args) -> tuple[float, dict]:
    started = time.perf_counter()
    result = fn(*args)
    return time.perf_counter() - started, result


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size-mb", type=float, default=100.0)
    ap.add_argument("--source", type=Path, default=SOURCE)
    ap.add_argument("--skip-dfreader", action="store_true", help="DFReader takes minutes on 100 MB")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory(prefix="bench_logs_") as tmp:
        path = synthesise(args.source, args.size_mb, Path(tmp) / "long.bin")
        size_mb = path.stat().st_size / 1e6
        first_s, _ = timed(ours, path)  # includes numba compile or cache load
        ours_s, result = timed(ours, path)
        print(f"ours: {size_mb:.1f} MB into flight tables in {ours_s:.2f} s (first run {first_s:.2f} s); "
              f"rows {result['rows']}")
        figures = {"log_mb": round(size_mb, 1), "ours_s": round(ours_s, 3), "ours_first_run_s": round(first_s, 3),
                   "ours_mb_per_s": round(size_mb / ours_s, 1)}
        if not args.skip_dfreader:
            df_s, df_result = timed(dfreader, path)
            print(f"DFReader: the same in {df_s:.1f} s; rows {df_result['rows']}")
            figures.update(dfreader_s=round(df_s, 2), speedup=round(df_s / ours_s, 1))
    figures.update(floors={"ours_s_max": FLOOR_S}, ok=ours_s < FLOOR_S, cpu_count=os.cpu_count(),
                   python=platform.python_version())
    print(json.dumps(figures))
    return 0


if __name__ == "__main__":
    sys.exit(main())
