"""A vehicle that sends no time_boot_ms is stamped with receive time (the tlog's stamps in a replay).
A stamp lies outside the packet's CRC, so a damaged one can be days ahead; a ground station's wall
clock can be stepped back. Receive time now passes the vehicle clock's rules: one stamp far off is
dropped, a step back continues the time from where it was, a real outage is taken once the next
messages agree (docs/mavlink.md, "Message time"). Before, one stamp 35 days ahead made every later
frame "out of order" (5,399 of 6,000 pack frames dropped, the pack's SoC stuck at 1.0)."""
import logging
import sys
from pathlib import Path

import numpy as np

from gcs_pdm.mavlink.replay import replay_tlog
from gcs_pdm.replay.vehicle import TracedPipeline
from gcs_pdm.vehicle.presets import PRESETS

sys.path.insert(0, str(Path(__file__).parent / "mavlink"))  # shared helpers; tests/ is not a package
from mavlink_builders import PacketFactory, tlog_record  # noqa: E402

T0_US = 1_700_000_000_000_000


def untimed_log(path, stamp_of=lambda i, us: us, seconds=600):
    """Heartbeats, battery and ESC telemetry, no time_boot_ms: 10 Hz, the pack draining slowly."""
    v = PacketFactory()
    packets = []
    for k in range(seconds * 10):
        if k % 10 == 0:
            packets.append(v.heartbeat())
        packets.append(v.battery(0, [4100 - k // 40] * 5, 2000, 3000))
        packets.append(v.esc([500] * 4, [5000] * 4, [40] * 4))
    stamps = [T0_US + 100_000 * i for i in range(len(packets))]
    path.write_bytes(b"".join(tlog_record(stamp_of(i, us), p) for i, (us, p) in enumerate(zip(stamps, packets))))
    return len(packets)


def replayed(path):
    frames = []
    pipeline = TracedPipeline(PRESETS["edge540"], {}, background=False)

    def consume(frame):
        frames.append(frame)
        pipeline(frame)

    summary = replay_tlog(path, frame_consumer=consume).to_dict()
    assert summary["vehicle"]["clock"] == "receive-time fallback"
    times = np.array([f.time_s for f in frames])
    return summary, times, pipeline.report()["estimate"]


def test_one_stamp_days_ahead_is_dropped_not_followed(tmp_path, caplog):
    untimed_log(tmp_path / "clean.tlog")
    untimed_log(tmp_path / "damaged.tlog", lambda i, us: us + (3_000_000 * 1_000_000 if i == 6_001 else 0))
    clean, clean_t, clean_est = replayed(tmp_path / "clean.tlog")
    with caplog.at_level(logging.WARNING):
        damaged, t, est = replayed(tmp_path / "damaged.tlog")
    assert damaged["mapping"]["time_rejected"] == 1
    assert 0 < clean["frames"] - damaged["frames"] <= 4  # that one message's frames, nothing after it
    assert np.all(np.diff(t) >= -1e-9) and t.max() < clean_t.max() + 1.0
    assert est["counters"].get("out_of_order", 0) == 0
    assert est["packs"]["LLF20"]["soc"] == clean_est["packs"]["LLF20"]["soc"]
    assert any("receive time" in r.getMessage() and "disagrees" in r.getMessage() for r in caplog.records)


def test_a_clock_stepped_back_continues_from_where_it_was(tmp_path):
    back_us = 60_000_000
    n = untimed_log(tmp_path / "back.tlog", lambda i, us: us - (back_us if i >= 9_000 else 0))
    summary, t, est = replayed(tmp_path / "back.tlog")
    assert np.all(np.diff(t) >= -1e-9), "message time ran backwards"
    # the step is confirmed by the next messages (about 2 s of them dropped), then time goes on
    assert 0 < summary["mapping"]["time_rejected"] < 100
    assert t.max() > T0_US / 1e6 + (n - 1) * 0.1 - 10  # not 60 s short: it went on from where it was
    assert est["counters"].get("out_of_order", 0) == 0


def test_a_real_outage_is_followed_once_the_next_messages_agree(tmp_path):
    gap_us = 40_000_000
    n = untimed_log(tmp_path / "gap.tlog", lambda i, us: us + (gap_us if i >= 9_000 else 0))
    summary, t, est = replayed(tmp_path / "gap.tlog")
    assert np.all(np.diff(t) >= -1e-9)
    assert t.max() == T0_US / 1e6 + (n - 1) * 0.1 + gap_us / 1e6  # the 40 s are in message time
    assert 0 < summary["mapping"]["time_rejected"] < 100
