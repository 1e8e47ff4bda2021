"""Trust nothing that arrives on the link (issue 12): whose telemetry, message time, plausibility,
who else listens on our port."""
from __future__ import annotations

import math
import socket
import sys
from pathlib import Path

import pytest

from gcs_pdm.frames import AmbientFrame, MotorFrame, PackFrame
from gcs_pdm.mavlink.clock import VehicleClock
from gcs_pdm.mavlink.connection import DEFAULT_SOURCE_SYSTEM, Link, LinkConfig, LinkError, check_link_url
from gcs_pdm.mavlink.mapping import FrameMapper
from gcs_pdm.mavlink.plausibility import FrameGate, PhysicalEnvelope, default_envelope
from gcs_pdm.mavlink.wire import split_packet
from gcs_pdm.models.params import builtin

sys.path.insert(0, str(Path(__file__).parent / "mavlink"))  # shared helpers; tests/ is not a package
from mavlink_builders import PacketFactory  # noqa: E402
from mavlink_peers import free_udp_port  # noqa: E402


def feed(mapper: FrameMapper, packet: bytes, recv_s: float) -> list:
    p = split_packet(packet)
    return list(mapper.feed(recv_s, p.msgid, p.sysid, p.compid, p.payload))


# --- whose telemetry ----------------------------------------------------------------------------

def test_a_foreign_vehicle_heard_first_is_never_adopted():
    vehicle, intruder = PacketFactory(1, 1), PacketFactory(42, 1)
    m = FrameMapper(target_system=1)
    assert feed(m, intruder.heartbeat(), 1.0) == []
    assert feed(m, intruder.battery(0, [42420], 100, 2000), 1.1) == []
    assert not m.locked
    feed(m, vehicle.heartbeat(), 2.0)
    feed(m, vehicle.position(5000), 2.0)
    feed(m, vehicle.position(5100), 2.1)
    assert (m.target_system, m.target_component) == (1, 1)
    pack, = feed(m, vehicle.battery(0, [4100] * 5, 100, 2000), 2.2)
    assert pack.voltage_v == pytest.approx(20.5)
    assert feed(m, intruder.battery(0, [42420], 100, 2000), 2.3) == []
    feed(m, intruder.heartbeat(), 2.4)
    foreign = m.foreign_systems[42]
    assert foreign.heartbeats == 2 and foreign.last_seen_s == pytest.approx(5.1)
    # Ground stations (autopilot INVALID) are expected company, not foreign vehicles.
    gcs = PacketFactory(255, 190)
    feed(m, gcs.pack(gcs.mav.heartbeat_encode(6, 8, 0, 0, 0)), 2.5)
    assert set(m.foreign_systems) == {42}


def test_link_defaults_track_system_1_and_send_as_its_own_system():
    cfg = LinkConfig()
    assert cfg.target_system == 1 and cfg.url == "udpin:127.0.0.1:14551"
    assert DEFAULT_SOURCE_SYSTEM not in (255, cfg.target_system)
    assert Link(cfg).mapper.target_system == 1


def test_foreign_heartbeats_on_a_live_link_are_reported(caplog):
    port = free_udp_port()
    link = Link(LinkConfig(url=f"udpin:127.0.0.1:{port}", heartbeat_hz=0)).start()
    try:
        tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        intruder = PacketFactory(42, 1)
        for _ in range(3):
            tx.sendto(intruder.heartbeat(), ("127.0.0.1", port))
        import time
        deadline = time.monotonic() + 5
        while not link.foreign_systems and time.monotonic() < deadline:
            time.sleep(0.02)
        time.sleep(0.1)
        assert [f.system for f in link.foreign_systems] == [42]
        assert link.trust_report()["foreign_systems"][0]["heartbeats"] == 3
        assert link.target_system == 1 and not link.mapper.locked
        assert sum("system 42" in r.getMessage() for r in caplog.records) == 1  # warned once
        tx.close()
    finally:
        link.close()


# --- who else listens -------------------------------------------------------------------------

def test_a_taken_udp_port_is_a_clear_error():
    port = free_udp_port()
    other = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    other.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # as pymavlink binds
    other.bind(("127.0.0.1", port))
    try:
        with pytest.raises(LinkError, match="already in use"):
            Link(LinkConfig(url=f"udpin:127.0.0.1:{port}")).open()
    finally:
        other.close()


def test_a_second_listener_cannot_share_our_port():
    port = free_udp_port()
    link = Link(LinkConfig(url=f"udpin:127.0.0.1:{port}")).open()
    try:
        with pytest.raises(LinkError, match="already in use"):
            Link(LinkConfig(url=f"udpin:127.0.0.1:{port}")).open()
        late = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        late.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # even a pymavlink-style bind
        with pytest.raises(OSError):
            late.bind(("127.0.0.1", port))
        late.close()
    finally:
        link.close()


@pytest.mark.parametrize("url, message", [
    ("udpin:127.0.0.1", "not understood"),
    ("udpin:127.0.0.1:99999", "out of range"),
    ("bogus:host:1", "not understood"),
    ("/dev/ttyNOSUCH0", "does not exist"),
    ("/bin/sh", "not a serial device"),  # pymavlink would execute it
])
def test_bad_urls_are_refused_before_pymavlink_sees_them(url, message):
    with pytest.raises(LinkError, match=message):
        check_link_url(url)


# --- message time -----------------------------------------------------------------------------

def _flying(m: FrameMapper, v: PacketFactory, boot_ms: int = 60_000) -> int:
    feed(m, v.heartbeat(), 0.0)
    for k in range(5):
        feed(m, v.position(boot_ms + 100 * k), 0.1 * k)
    return boot_ms + 400


def test_one_far_future_timestamp_does_not_move_message_time():
    v, m = PacketFactory(), FrameMapper()
    boot = _flying(m, v)
    assert feed(m, v.pressure(0xFFFFFFFF), 1.0) == []
    assert m.clock.now == pytest.approx(boot / 1000)
    assert m.stats.time_rejected == 1 and m.clock.rejected == 1
    # the vehicle's own messages go on at its own time
    assert feed(m, v.position(boot + 100), 1.1)[0].time_s == pytest.approx((boot + 100) / 1000)
    pack, = feed(m, v.battery(0, [4100] * 5, 100, 2000), 1.2)
    assert pack.time_s == pytest.approx((boot + 100) / 1000)


def test_hostile_timestamps_between_the_vehicles_never_win():
    v = PacketFactory()
    m = FrameMapper()
    boot = _flying(m, v)
    for k in range(50):  # many, of two types, but the vehicle keeps being heard in between
        feed(m, v.pressure(0xFFFFFF00 + k), 1.0 + k * 0.01)
        feed(m, v.position(0xFFFFFF00 + k), 1.0 + k * 0.01)
        feed(m, v.position(boot + 10 * k), 1.0 + k * 0.01)
    assert m.clock.now < 100 and m.clock.rejected == 100 and m.clock.jumps == 0


def test_a_flood_of_agreeing_lies_loses_to_the_vehicle():
    """Hundreds of consistent lies of two types between two of the vehicle's messages: not adopted."""
    v, m = PacketFactory(), FrameMapper()
    boot = _flying(m, v)
    for second in range(10):
        for k in range(300):
            recv = 1.0 + second + k / 300
            feed(m, v.pressure(0xFFFFF000 + k), recv)
            feed(m, v.position(0xFFFFF000 + k), recv)
        feed(m, v.position(boot + 1000 * second), 1.0 + second + 0.999)  # the vehicle at 1 Hz
    assert m.clock.now < 100 and m.clock.jumps == 0 and m.clock.reboots == 0


def test_a_real_outage_is_accepted_when_the_streams_agree():
    v, m = PacketFactory(), FrameMapper()
    boot = _flying(m, v)
    later = boot + 60_000  # one minute without telemetry
    steps = int(VehicleClock.CONFIRM_SPAN_S / 0.5) + 1  # two streams at 2 Hz for the confirmation span
    for k in range(steps):
        feed(m, v.position(later + 500 * k), 61.0 + 0.5 * k)
        feed(m, v.pressure(later + 500 * k + 5), 61.0 + 0.5 * k)
    assert m.clock.jumps == 1 and m.clock.now == pytest.approx((later + 500 * (steps - 1) + 5) / 1000)
    # one stream alone is not enough to jump
    m2 = FrameMapper()
    _flying(m2, v)
    for k in range(3 * steps):
        feed(m2, v.position(later + 500 * k), 61.0 + 0.5 * k)
    assert m2.clock.jumps == 0 and m2.clock.now < 100


def test_a_hostile_first_timestamp_does_not_set_the_clock():
    v, m = PacketFactory(), FrameMapper()
    feed(m, v.heartbeat(), 0.0)
    assert feed(m, v.pressure(0xFFFFFFFF), 0.0) == []
    frames = feed(m, v.position(60_000), 0.1) + feed(m, v.position(60_100), 0.2)
    assert m.clock.now == pytest.approx(60.1)
    assert all(f.time_s < 61 for f in frames) and m.stats.time_rejected == 1


# --- plausibility -----------------------------------------------------------------------------

def test_envelope_from_the_parameter_set_counts_cells():
    env = PhysicalEnvelope.from_parameter_set(builtin("paper_si"))  # 21 V packs: 5S
    lo, hi = env.pack_voltage_v["LLF20"]
    assert lo == pytest.approx(5 * 2.5 * 0.95) and hi == pytest.approx(5 * 4.35 * 1.05)
    assert PhysicalEnvelope.from_packs({"A": 12}).pack_voltage_v["A"][1] == pytest.approx(12 * 4.35 * 1.05)


def test_values_no_pack_can_produce_become_missing_and_are_counted():
    v, m = PacketFactory(), FrameMapper()
    _flying(m, v)
    pack, = feed(m, v.battery(2, [65534, 35466], 1500, 2750), 1.0)  # 101 V on a 21 V pack
    assert pack.voltage_v is None and pack.current_a == pytest.approx(15.0) and pack.temperature_c == 27.5
    ambient, = feed(m, v.pressure(60_450, -30000), 1.1)  # -300 °C
    assert ambient.temperature_c is None
    assert m.stats.to_dict()["gated"] == {"ambient.temperature_c.below_range": 1, "pack.voltage_v.above_range": 1}


def test_gate_handles_non_finite_and_huge_values():
    gate = FrameGate(default_envelope())
    assert gate(MotorFrame(1.0, "fwd", 12.0, 5000.0, 1e69)) == MotorFrame(1.0, "fwd", 12.0, 5000.0, None)
    assert gate(PackFrame(1.0, "LLF20", math.nan, -1e9, -1e69)) == PackFrame(1.0, "LLF20", None, None, None)
    assert gate(AmbientFrame(1.0, 21.0)) == AmbientFrame(1.0, 21.0)
    assert gate.counts() == {"motor.temperature_c.above_range": 1, "pack.current_a.below_range": 1,
                             "pack.temperature_c.below_range": 1, "pack.voltage_v.not_finite": 1}


def test_mapping_gates_as_the_gate_does_whatever_the_values():
    """The mapping tests the gate's ranges where it builds a frame (issue 18): every frame it makes
    equals the gate applied to the ungated frame, and the counts are the gate's."""
    import random

    rng = random.Random(18)
    v = PacketFactory()
    gated, plain = FrameMapper(), FrameMapper(envelope=None)
    reference, reference_by_field = FrameGate(default_envelope()), FrameGate(default_envelope())
    _flying(gated, v)
    _flying(plain, v)
    # a mapping whose pack names come from a message field: the gate looks the range up per frame
    by_field = FrameMapper({"NAMED_VALUE_FLOAT": [{"frame": "pack", "fields": {"pack": {"field": "name", "text": True},
                                                                                  "voltage_v": {"field": "value"}}}]})
    _flying(by_field, v)
    unsigned, signed = [0, 1, 4100, 65534, 65535], [0, 1, 32767, -32768, -1]
    for i in range(400):
        pack_id = rng.randrange(4)
        cells = [rng.choice(unsigned + [rng.randrange(65536)]) for _ in range(rng.randrange(1, 6))]
        packets = [v.battery(pack_id, cells, rng.choice(signed + [rng.randrange(-32768, 32768)]),
                             rng.choice(signed + [rng.randrange(-32768, 32768)])),
                   v.esc([rng.randrange(65536) for _ in range(4)], [rng.randrange(65536) for _ in range(4)],
                         [rng.randrange(256) for _ in range(4)]),
                   v.pressure(60_000 + i, rng.randrange(-32768, 32768)),
                   v.position(60_000 + i, rng.randrange(-2 ** 31, 2 ** 31), rng.randrange(-2 ** 31, 2 ** 31)),
                   v.hud(airspeed=rng.choice([math.nan, math.inf, -5.0, 20.0, 1e30]))]
        for packet in packets:
            want = [reference(f) for f in feed(plain, packet, 60.0 + i / 1000)]
            assert feed(gated, packet, 60.0 + i / 1000) == want
        name = rng.choice(["LLF20", "LLF23", "nobody"]).encode()
        value = rng.choice([math.nan, 0.0, 21.0, 101.0])
        frame, = feed(by_field, v.pack(v.mav.named_value_float_encode(60_000 + i, name, value)), 60.0 + i / 1000)
        raw = None if math.isnan(value) else value  # the mapping's "not available"
        assert frame == reference_by_field(PackFrame(frame.time_s, name.decode(), raw, None, None))
    assert gated.stats.to_dict()["gated"] == reference.counts() != {}
    assert by_field.stats.to_dict()["gated"] == reference_by_field.counts() != {}


def test_service_setting_target_system_takes_an_id_or_auto():
    from gcs_pdm.service.config import ConfigError, load_config

    assert load_config(env={}).target_system == 1
    assert load_config(env={"GCS_PDM_TARGET_SYSTEM": "auto"}).target_system == "auto"
    assert load_config(env={"GCS_PDM_TARGET_SYSTEM": "7"}).target_system == 7
    for bad in ("any", "0", "256"):
        with pytest.raises(ConfigError, match="^target_system"):
            load_config(env={"GCS_PDM_TARGET_SYSTEM": bad})
    with pytest.raises(ConfigError, match="^source_system"):
        load_config(env={"GCS_PDM_SOURCE_SYSTEM": "255"})  # the GCS's id is not ours


def test_vehicle_silence_counts_only_the_tracked_vehicles_heartbeats():
    link = Link(LinkConfig(url="udpin:127.0.0.1:1", heartbeat_hz=0))  # never opened: packets injected
    vehicle, intruder = PacketFactory(1, 1), PacketFactory(42, 1)

    def inject(packet: bytes) -> None:
        from gcs_pdm.mavlink.dialect import mavlink2
        msg = mavlink2.MAVLink(None).decode(bytearray(packet))
        link.handle_message(msg)

    inject(intruder.heartbeat())
    assert link.vehicle_silent_s() is None  # a stranger's heartbeat is not the vehicle's
    inject(vehicle.heartbeat())
    assert 0 <= link.vehicle_silent_s() < 1
    import time
    assert link.vehicle_silent_s(now=time.monotonic() + 5) > 4.9
