"""Two senders behind the vehicle's system/component id interleave their MAVLink sequence numbers;
one sender on a lossy link never steps back. The mapping cannot tell such packets apart, so the
replay summary and the live link's trust report say it (gcs_pdm/mavlink/sequence.py)."""
import logging
import sys
from pathlib import Path

import numpy as np

from gcs_pdm.mavlink.connection import Link, LinkConfig
from gcs_pdm.mavlink.dialect import mavlink2
from gcs_pdm.mavlink.replay import replay_tlog
from gcs_pdm.mavlink.sequence import SequenceMonitor, sequence_stats

sys.path.insert(0, str(Path(__file__).parent / "mavlink"))  # shared helpers; tests/ is not a package
from mavlink_builders import PacketFactory, tlog_record  # noqa: E402


def write_tlog(path, packets):
    path.write_bytes(b"".join(tlog_record(1_700_000_000_000_000 + 100_000 * k, p) for k, p in enumerate(packets)))


def flight(vehicle, n=300):
    for k in range(n):
        if k % 10 == 0:
            yield vehicle.heartbeat()
        yield vehicle.battery(0, [4000] * 4, 1500, 3000)


def test_a_second_sender_on_the_vehicles_id_is_said(tmp_path, caplog):
    ours, other = PacketFactory(1, 1, numbered=True), PacketFactory(1, 1, numbered=True)
    other.mav.seq = 117  # its own counter, somewhere else
    mixed = [p for pair in zip(flight(ours), flight(other)) for p in pair]
    write_tlog(tmp_path / "two.tlog", mixed)
    with caplog.at_level(logging.WARNING, logger="gcs_pdm.mavlink.replay"):
        seq = replay_tlog(tmp_path / "two.tlog").to_dict()["vehicle"]["sequence"]
    assert seq["shared"] and seq["shared_now"] and seq["out_of_sequence"] >= 0.4 * seq["packets"]
    assert "more than one sender uses system 1 component 1" in seq["verdict"]
    assert any("more than one sender" in r.getMessage() for r in caplog.records)


def test_one_sender_losing_packets_is_one_sender(tmp_path):
    packets = list(flight(PacketFactory(1, 1, numbered=True)))
    rng = np.random.default_rng(0)
    kept = [p for p in packets if rng.random() > 0.2]  # a fifth of the packets lost
    write_tlog(tmp_path / "lossy.tlog", kept)
    seq = replay_tlog(tmp_path / "lossy.tlog").to_dict()["vehicle"]["sequence"]
    assert not seq["shared"] and seq["verdict"] == "one sender"
    assert seq["packets"] == len(kept) and seq["out_of_sequence"] == 0
    assert seq["lost"] == len(packets) - len(kept) - (packets.index(kept[0]))


def test_the_live_monitor_counts_as_the_replay_does():
    rng = np.random.default_rng(1)
    seqs = np.concatenate([np.arange(500) % 256, (np.arange(300) + 40) % 256])
    rng.shuffle(seqs[450:])  # a stretch where two counters interleave
    live = SequenceMonitor()
    for s in seqs:
        live.note(1, 1, int(s))
    batch = sequence_stats(np.ones(seqs.size), np.ones(seqs.size), seqs, (1, 1))
    assert live.stats(1, 1) == batch and batch.shared


def test_a_sender_that_starts_late_in_a_long_session_is_not_diluted():
    ours = np.arange(20_000) % 256                      # an hour and more of one sender
    other = (np.arange(300) + 77) % 256                 # then a second one on the same ids
    seqs = np.concatenate([ours, np.ravel(np.column_stack([(np.arange(20_000, 20_300)) % 256, other]))])
    live = SequenceMonitor()
    for s in seqs:
        live.note(1, 1, int(s))
    st = live.stats(1, 1)
    assert st.shared_now and st.out_of_sequence < 0.05 * st.packets   # diluted over the whole session
    assert st == sequence_stats(np.ones(seqs.size), np.ones(seqs.size), seqs, (1, 1))
    # and once it has gone, the latest window is clean again; the verdict says it was there
    for s in (np.arange(20_300, 21_000) % 256):
        live.note(1, 1, int(s))
    st = live.stats(1, 1)
    assert not st.shared_now and st.shared and "earlier" in st.verdict


def test_the_live_links_trust_report_says_it():
    link = Link(LinkConfig(url="udpin:127.0.0.1:1", heartbeat_hz=0))  # never opened: packets injected
    ours, other = PacketFactory(1, 1, numbered=True), PacketFactory(1, 1, numbered=True)
    other.mav.seq = 117
    assert link.trust_report()["sequence"] is None  # no vehicle yet
    for a, b in zip(flight(ours, 100), flight(other, 100)):
        for packet in (a, b):
            link.handle_message(mavlink2.MAVLink(None).decode(bytearray(packet)))
    seq = link.trust_report()["sequence"]
    assert seq["system"] == 1 and seq["shared"] and seq["packets"] == 220
