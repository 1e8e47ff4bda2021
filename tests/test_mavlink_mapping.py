"""Message -> frame mapping: units, sentinels, configuration changes, vehicle filter, clock."""
from __future__ import annotations

import sys
from pathlib import Path

import pytest

from gcs_pdm.frames import AirdataFrame, AmbientFrame, MotorFrame, PackFrame, PositionFrame, StatusFrame
from gcs_pdm.mavlink.clock import VehicleClock
from gcs_pdm.mavlink.mapping import FrameMapper, MappingError, default_mapping
from gcs_pdm.mavlink.wire import split_packet

sys.path.insert(0, str(Path(__file__).parent / "mavlink"))  # shared helpers; tests/ is not a package
from mavlink_builders import PacketFactory  # noqa: E402


def feed(mapper: FrameMapper, packet: bytes, recv_s: float):
    p = split_packet(packet)
    return list(mapper.feed(recv_s, p.msgid, p.sysid, p.compid, p.payload))


def started(mapper: FrameMapper, v: PacketFactory, boot_ms: int = 5000, recv_s: float = 100.0) -> list:
    """Heartbeat, then the same position until the clock has confirmed the vehicle's time."""
    out = feed(mapper, v.heartbeat(), recv_s)
    for _ in range(VehicleClock.ACQUIRE_SAMPLES):
        out += feed(mapper, v.position(boot_ms), recv_s)
    return out


def test_units_and_keys():
    v, m = PacketFactory(), FrameMapper()
    frames = started(m, v)
    assert frames[0] == StatusFrame(5.0, True, "AUTO", 4)
    assert frames[1] == PositionFrame(5.0, 47.3977419, 8.5455938, 500.0, 100.0, 15.0, -2.0, 0.3)
    assert feed(m, v.battery(2, [4100, 4100, 4100, 4100, 4100], 1534, 2750), 100.1) == [
        PackFrame(5.0, "LRF40", pytest.approx(20.5), pytest.approx(15.34), pytest.approx(27.5))]
    motors = feed(m, v.esc([1250, 980, 0, 0], [5400, 5300, 0, 0], [61, 58, 0, 0]), 100.2)
    assert motors == [MotorFrame(5.0, "fwd", pytest.approx(12.5), 5400, 61),
                      MotorFrame(5.0, "aft", pytest.approx(9.8), 5300, 58)]
    assert feed(m, v.pressure(5100, 2150), 100.3) == [AmbientFrame(5.1, pytest.approx(21.5))]
    assert feed(m, v.hud(18.0, 55), 100.4) == [AirdataFrame(5.1, 18.0, 17.0, 1.5, 55, 90)]


def test_not_available_sentinels_become_none():
    v, m = PacketFactory(), FrameMapper(envelope=None)  # 76 V is no pack of the default set
    started(m, v)
    # No cell voltages, current -1 (not measured), temperature INT16_MAX (unknown).
    frame, = feed(m, v.pack(v.mav.battery_status_encode(0, 0, 0, 32767, [65535] * 10, -1, -1, -1, -1)), 100.1)
    assert frame == PackFrame(5.0, "LLF20", None, None, None)
    # Total voltage above 65.534 V is split over cells 0 and 1 (MAVLink spec) and summed back.
    frame, = feed(m, v.battery(1, [65534, 10466], 500, 2000), 100.2)
    assert frame.voltage_v == pytest.approx(76.0)


def test_unmapped_pack_ids_are_counted_not_guessed():
    v, m = PacketFactory(), FrameMapper()
    started(m, v)
    assert feed(m, v.battery(7, [4000] * 5, 100, 2000), 100.1) == []
    assert m.stats.unmapped_keys[("BATTERY_STATUS", 7)] == 1


def test_mapping_is_configuration():
    mapping = default_mapping()
    # A vehicle whose packs report ids in another order...
    mapping["BATTERY_STATUS"][0]["key"]["map"] = {"0": "URA40", "1": "LRF40", "2": "ULA20", "3": "LLF20"}
    # ...and that sends the front motor temperature as NAMED_VALUE_FLOAT "MOT_TEMP".
    mapping["NAMED_VALUE_FLOAT"] = [{"frame": "motor", "match": {"name": "MOT_TEMP"},
                                     "key": {"const": "fwd", "target": "motor"},
                                     "fields": {"temperature_c": {"field": "value"}}}]
    v, m = PacketFactory(), FrameMapper(mapping)
    started(m, v)
    assert feed(m, v.battery(0, [4000] * 5, 100, 2000), 100.1)[0].pack == "URA40"
    assert feed(m, v.pack(v.mav.named_value_float_encode(5200, b"MOT_TEMP", 71.5)), 100.2) == [
        MotorFrame(5.2, "fwd", None, None, 71.5)]
    assert feed(m, v.pack(v.mav.named_value_float_encode(5300, b"OTHER", 1.0)), 100.3) == []


@pytest.mark.parametrize("broken, message", [
    ({"NO_SUCH_MSG": [{"frame": "pack"}]}, "unknown message"),
    ({"BATTERY_STATUS": [{"frame": "pack", "fields": {"voltage_v": {"field": "volts"}}}]}, "no field 'volts'"),
    ({"VFR_HUD": [{"frame": "airplane"}]}, "unknown frame kind"),
    ({"VFR_HUD": [{"frame": "airdata", "fields": {"mach": {"field": "airspeed"}}}]}, "no field 'mach'"),
    ({"VFR_HUD": [{"frame": "airdata", "fields": {"airspeed": {"field": "airspeed", "scale": "inf"}}}]},
     "must be finite"),
])
def test_bad_mapping_names_the_problem(broken, message):
    with pytest.raises(MappingError, match=message):
        FrameMapper(broken)


def test_only_the_vehicle_is_used():
    vehicle, gcs, other = PacketFactory(1, 1), PacketFactory(255, 190), PacketFactory(2, 1)
    m = FrameMapper()
    # A GCS heartbeat (autopilot INVALID) does not identify the vehicle; the autopilot's does.
    gcs_hb = gcs.pack(gcs.mav.heartbeat_encode(6, 8, 0, 0, 0))
    assert feed(m, gcs_hb, 1.0) == [] and not m.locked
    started(m, vehicle)
    assert (m.target_system, m.target_component) == (1, 1)
    assert feed(m, other.position(9000), 100.5) == []
    assert feed(m, gcs_hb, 100.6) == []
    assert m.stats.other_source == 2


def test_untimed_messages_take_the_latest_vehicle_time_not_receive_time():
    """A vehicle simulated 10x faster than real time gives the same frame times."""
    def run(time_scale: float) -> list:
        v, m = PacketFactory(), FrameMapper()
        out = started(m, v, boot_ms=9_900, recv_s=999.9)
        for i in range(50):
            recv = 1000.0 + i * 0.1 * time_scale
            out += feed(m, v.position(10_000 + 100 * i), recv)
            out += feed(m, v.battery(0, [4000] * 5, 1000 + i, 2000), recv + 0.01 * time_scale)
            out += feed(m, v.heartbeat(), recv + 0.02 * time_scale)
        return out

    real_time, fast = run(1.0), run(0.1)
    assert real_time == fast
    packs = [f for f in real_time if isinstance(f, PackFrame)]
    assert [round(f.time_s, 3) for f in packs[:3]] == [10.0, 10.1, 10.2]


def test_reboot_keeps_time_running_forward():
    v, m = PacketFactory(), FrameMapper()
    feed(m, v.heartbeat(), 0.0)
    feed(m, v.position(599_900), 9.9)
    before = feed(m, v.position(600_000), 10.0)[-1].time_s
    assert before == 600.0
    # Rebooted: time_boot_ms restarts. One message is not proof; consistent follow-ups near zero,
    # over the confirmation span, are.
    span_steps = int(VehicleClock.CONFIRM_SPAN_S / 0.5)
    for k in range(span_steps):
        assert feed(m, v.position(1_500 + 500 * k), 12.0 + 0.5 * k) == []
    after = feed(m, v.position(1_500 + 500 * span_steps), 12.0 + 0.5 * span_steps)[-1].time_s
    assert after == pytest.approx(602.0 + 0.5 * span_steps)  # after the 2 s receive gap
    assert m.clock.reboots == 1
    assert feed(m, v.position(1_500 + 500 * (span_steps + 1)), 13.0 + 0.5 * span_steps)[-1].time_s == pytest.approx(
        602.0 + 0.5 * (span_steps + 1))


def test_frames_before_the_first_timed_message_are_back_dated():
    v, m = PacketFactory(), FrameMapper()
    assert feed(m, v.heartbeat(), 50.0) == []  # waits for the clock
    assert feed(m, v.position(7_000), 50.5) == []  # one timestamp does not set the clock...
    frames = feed(m, v.position(7_100), 50.6)  # ...two that agree do
    assert [type(f) for f in frames] == [StatusFrame, PositionFrame, PositionFrame]
    assert [f.time_s for f in frames] == [pytest.approx(6.5), 7.0, 7.1]


def test_vehicle_without_time_fields_falls_back_to_receive_time():
    v, m = PacketFactory(), FrameMapper(sync_window_s=3.0)
    assert feed(m, v.heartbeat(), 100.0) == []
    frames = feed(m, v.hud(), 104.0)
    assert [f.time_s for f in frames] == [100.0, 104.0]
    assert m.clock.fallback
