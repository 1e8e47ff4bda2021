"""The replay's column mapping (``gcs_pdm.mavlink.frame_columns``) gives exactly the frames and
counters of feeding the live link's ``FrameMapper`` one message at a time: on the fixture flights,
the real logs of the shared corpus, and randomly generated damaged logs (truncated and extended
payloads, MAVLink 1, NaN/inf, out-of-range values, unmapped keys, duplicates, out-of-order time,
reboots, jumps, hostile timestamps, receive-time fallback, foreign systems and components)."""
from __future__ import annotations

import glob
import math
import random
import struct
from pathlib import Path

import numpy as np
import pytest
from fastcrc.crc16 import mcrf4xx

import gcs_pdm.mavlink.frame_columns as frame_columns
import gcs_pdm.mavlink.replay as replay
from gcs_pdm.mavlink.clock import Verdict, VehicleClock
from gcs_pdm.mavlink.dialect import CRC_EXTRA, MESSAGE_CLASSES, MESSAGE_IDS_BY_NAME
from gcs_pdm.mavlink.mapping import FrameMapper, default_mapping
from gcs_pdm.mavlink.tlog import scanned_tlog, take_kept_scan
from gcs_pdm.mavlink.wire import layout

REPO = Path(__file__).resolve().parents[1]
SHARED = REPO / ".." / "shared"
REAL_LOGS = sorted(glob.glob(str(SHARED / "tlogs" / "*.tlog"))) + sorted(glob.glob(str(SHARED / "logs" / "*.tlog")))
FIXTURE_LOGS = sorted(glob.glob(str(REPO / "fixtures" / "flights" / "*.tlog")))


# --- the two ways, and everything they leave behind --------------------------------------------

def _clock_state(clock: VehicleClock) -> str:
    state = dict(vars(clock))
    candidate = state.pop("_candidate")
    state["candidate"] = None if candidate is None else {k: getattr(candidate, k) for k in candidate.__slots__}
    receive = state.pop("_receive", None)  # after the fallback: the receive-time clock, compared the same way
    state["receive"] = None if receive is None else _clock_state(receive)
    return repr(sorted(state.items()))


def _counts(counter) -> list:
    """A counter's entries whatever their order (keys by repr: a NaN key from a float field is its own)."""
    return sorted((repr(k), v) for k, v in counter.items())


def _mapper_state(mapper: FrameMapper) -> tuple:
    stats = mapper.stats
    return (stats.other_source, stats.before_vehicle, stats.undecodable, stats.time_rejected,
            _counts(stats.frames_by_kind), _counts(stats.unmapped_keys), _counts(stats.gated),
            (mapper.target_system, mapper.target_component, mapper.locked), _clock_state(mapper.clock),
            {k: v.to_dict() for k, v in mapper.foreign_systems.items()}, repr(mapper._pending))


def mapped_both_ways(path, make_mapper) -> tuple[list, FrameMapper]:
    """The frames (flush included) of a log fed message by message and mapped by type, asserted equal
    (``repr``: values, their Python types, -0.0 and NaN alike), and the mapper states asserted equal."""
    scanned = scanned_tlog(path)
    take_kept_scan(path)
    one = make_mapper()
    by_message = [f for frames in replay._frames_by_message(one, zip(*scanned.columns), scanned.data) for f in frames]
    by_message += one.flush()
    other = make_mapper()
    by_type = [f for frames in replay._frames_by_type(other, scanned) for f in frames]
    by_type += other.flush()
    assert len(by_type) == len(by_message), path
    for i, (a, b) in enumerate(zip(by_type, by_message)):
        assert repr(a) == repr(b), f"{path}: frame {i}"
    assert _mapper_state(other) == _mapper_state(one), path
    return by_message, other


@pytest.fixture
def columnar_calls(monkeypatch):
    """The share of its records each replay mapped by type (the test is void if none did)."""
    calls = []

    def spy(mapper, data, columns, start):
        calls.append((len(columns[0]) - start) / len(columns[0]))
        return frame_columns.map_scanned(mapper, data, columns, start)
    monkeypatch.setattr(replay, "map_scanned", spy)
    return calls


@pytest.mark.parametrize("path", FIXTURE_LOGS + REAL_LOGS, ids=lambda p: Path(p).name)
def test_real_and_fixture_logs(path, columnar_calls):
    frames, _ = mapped_both_ways(path, FrameMapper)
    assert frames and columnar_calls[0] > 0.5  # the rest after the clock synced


def test_the_description_mapping_and_envelope(columnar_calls):
    """As ``gcs-pdm replay`` maps a log: the vehicle description's mapping and per-pack envelope."""
    from gcs_pdm.vehicle.presets import PRESETS
    from gcs_pdm.mavlink.vehicle_mapping import envelope, frame_mapping

    for name, desc in PRESETS.items():
        for path in FIXTURE_LOGS[:3]:
            mapped_both_ways(path, lambda: FrameMapper(frame_mapping(desc), envelope=envelope(desc)))
    assert len(columnar_calls) == 3 * len(PRESETS)


# --- randomly generated damaged logs ------------------------------------------------------------

def _payload(message: str, **values) -> bytes:
    """A message's full payload from its fields (the others zero), packed in wire order."""
    lay = layout(MESSAGE_IDS_BY_NAME[message])
    flat = []
    for field, (code, repeat) in lay.codes.items():
        default = b"" if code == "s" else [0] * int(repeat) if repeat else 0
        value = values.get(field, default)
        flat += value if isinstance(value, list) else [value]
    return lay.struct.pack(*flat)


def _packet(msgid: int, payload: bytes, sysid: int, compid: int, seq: int, v1: bool) -> bytes:
    if v1:
        header = bytes([0xFE, len(payload), seq & 255, sysid, compid, msgid])
    else:
        header = bytes([0xFD, len(payload), 0, 0, seq & 255, sysid, compid]) + msgid.to_bytes(3, "little")
    crc = mcrf4xx(bytes((CRC_EXTRA[msgid],)), mcrf4xx(header[1:] + payload))
    return header + payload + crc.to_bytes(2, "little")


ODD_FLOATS = [math.nan, math.inf, -math.inf, -0.0, -3.0, 500.0, 1e30]
TIMED = {"GLOBAL_POSITION_INT", "SCALED_PRESSURE", "SYSTEM_TIME", "ATTITUDE", "NAMED_VALUE_FLOAT"}


def _message(rng: random.Random, boot_ms: int) -> tuple[str, bytes]:
    f = rng.random
    odd = lambda normal: rng.choice(ODD_FLOATS) if f() < 0.15 else normal  # noqa: E731
    name = rng.choice(["HEARTBEAT", "BATTERY_STATUS", "BATTERY_STATUS", "ESC_TELEMETRY_1_TO_4", "GLOBAL_POSITION_INT",
                       "GLOBAL_POSITION_INT", "VFR_HUD", "VFR_HUD", "SCALED_PRESSURE", "MISSION_CURRENT",
                       "MISSION_ITEM_REACHED", "STATUSTEXT", "SYSTEM_TIME", "SYS_STATUS", "ATTITUDE", "NAMED_VALUE_FLOAT"])
    if f() < 0.07:  # any bytes at all: random floats, times, keys
        return name, bytes(rng.randrange(256) for _ in range(layout(MESSAGE_IDS_BY_NAME[name]).size))
    if name == "HEARTBEAT":
        return name, _payload(name, type=rng.choice([1, 2, 6, 13]), autopilot=rng.choice([3, 3, 3, 8, 12]),
                              base_mode=rng.choice([0x81, 0x01, 0xD9, 0]), custom_mode=rng.randrange(30),
                              system_status=rng.randrange(9), mavlink_version=3)
    if name == "BATTERY_STATUS":
        return name, _payload(name, id=rng.choice([0, 1, 2, 3, 7]), temperature=rng.choice([32767, 2500, -500, 30000]),
                              voltages=rng.choice([[65535] * 10, [0] * 10, [4100] * 4 + [65535] * 6, [60000] * 10,
                                                   [rng.randrange(2000, 4400)] * 6 + [65535] * 4]),
                              current_battery=rng.choice([-1, 0, 150, 2500, 32000, -20000]),
                              voltages_ext=rng.choice([[0] * 4, [4000, 0, 0, 0], [65535] * 4]))
    if name == "ESC_TELEMETRY_1_TO_4":
        return name, _payload(name, temperature=[rng.randrange(256) for _ in range(4)],
                              current=[rng.choice([0, 1200, 65535]) for _ in range(4)],
                              rpm=[rng.choice([0, 5400, 65535]) for _ in range(4)])
    if name == "GLOBAL_POSITION_INT":
        return name, _payload(name, time_boot_ms=boot_ms, lat=rng.choice([473977419, 2147483647, -900000001]),
                              lon=rng.choice([85455938, -1800000001]), alt=rng.choice([500_000, -600_000, 20_000_000]),
                              relative_alt=100_000, vx=rng.randrange(-3000, 3000), vy=-200, vz=30, hdg=9000)
    if name == "VFR_HUD":
        return name, _payload(name, airspeed=odd(18.0), groundspeed=odd(17.5), alt=120.0, climb=odd(0.5),
                              heading=rng.randrange(-10, 370), throttle=rng.randrange(0, 120))
    if name == "SCALED_PRESSURE":
        return name, _payload(name, time_boot_ms=boot_ms, press_abs=1013.0, press_diff=odd(0.5),
                              temperature=rng.choice([2150, -9000, 20000, 0]))
    if name in ("MISSION_CURRENT", "MISSION_ITEM_REACHED"):
        return name, _payload(name, seq=rng.randrange(0, 20))
    if name == "STATUSTEXT":
        text = bytes(rng.randrange(1, 256) for _ in range(rng.randrange(0, 50)))
        return name, _payload(name, severity=rng.randrange(8), text=text)
    if name == "SYSTEM_TIME":
        return name, _payload(name, time_unix_usec=rng.choice([0, 1_700_000_000_000_000, 2 ** 63 + 1]),
                              time_boot_ms=boot_ms)
    if name == "ATTITUDE":
        return name, _payload(name, time_boot_ms=boot_ms, roll=odd(0.1), pitch=odd(-0.2), yaw=1.0)
    if name == "NAMED_VALUE_FLOAT":
        return name, _payload(name, time_boot_ms=boot_ms, name=rng.choice([b"MOT_TEMP", b"ESC_T", b"MOT_TEMP\0x"]),
                              value=odd(rng.choice([1.0, 2.0, 45.5])))
    return name, bytes(rng.randrange(256) for _ in range(layout(MESSAGE_IDS_BY_NAME[name]).size))


def random_log(rng: random.Random, messages: int) -> bytes:
    """A tlog with the oddities a mapping meets (see the module docstring)."""
    out = []
    boot_ms = rng.choice([0, 1000, rng.randrange(0, 4_000_000)])
    recv_us = 1_700_000_000_000_000
    untimed_until = recv_us + rng.choice([0, 0, 0, 35_000_000])  # > the 30 s sync window: receive-time fallback
    lock_after = rng.choice([0, 0, 5, 40])  # messages from others before the vehicle's first heartbeat
    for i in range(messages):
        recv_us += rng.choice([1000, 5000, 20_000, 100_000, 400_000])
        if rng.random() < 0.01:
            recv_us += rng.choice([40_000_000, -2_000_000])
        boot_ms += rng.randrange(0, 300)
        r = rng.random()
        if r < 0.01:
            boot_ms = rng.randrange(0, 5000)  # a reboot
        elif r < 0.02:
            boot_ms += rng.randrange(11_000, 90_000)  # a jump (a link outage)
        stamp = boot_ms
        if rng.random() < 0.02:
            stamp = rng.randrange(0, 2 ** 32)  # one hostile or garbled timestamp
        elif rng.random() < 0.03:
            stamp = max(0, boot_ms - rng.randrange(0, 3000))  # out of order between streams
        name, payload = _message(rng, stamp)
        if name in TIMED and recv_us < untimed_until:
            name, payload = "VFR_HUD", _payload("VFR_HUD", airspeed=12.0)
        source = rng.choices([(1, 1), (1, 2), (2, 1), (255, 190), (3, 1)], [85, 5, 4, 4, 2])[0]
        if i < lock_after:
            source = (255, 190)
            if name == "HEARTBEAT":
                payload = _payload(name, type=6, autopilot=8)
        msgid = MESSAGE_IDS_BY_NAME[name]
        v1 = msgid < 256 and rng.random() < 0.1
        trimmed = payload.rstrip(b"\0") or payload[:1]  # MAVLink 2 drops trailing zeros
        r = rng.random()
        if r < 0.12:
            trimmed = payload[:rng.randrange(0, len(payload) + 1)]  # cut shorter: the rest reads as zeros
        elif r < 0.17:
            trimmed = payload + bytes(rng.randrange(256) for _ in range(rng.randrange(1, 8)))  # a newer dialect's extension
        packet = _packet(msgid, trimmed, *source, i, v1)
        record = struct.pack(">Q", recv_us) + packet
        out.append(record)
        if rng.random() < 0.02:
            out.append(record)  # a duplicate
    data = bytearray(b"".join(out))
    if rng.random() < 0.3:  # some bytes overwritten: bad CRCs and garbage for the scanner to skip
        for _ in range(len(data) // 800):
            data[rng.randrange(len(data))] = rng.randrange(256)
    return bytes(data)


def _custom_mapping() -> dict:
    """The default mapping and rules of every other kind: a match on text, a constant key, several
    rules of one message, an index spec, an offset and a scale that is not 1/N, a sum of floats, an
    integer in a gated field — and rules the column mapping leaves to the per-message builder (a
    float key, a transform under the gate, a 64-bit field)."""
    mapping = default_mapping()
    mapping["NAMED_VALUE_FLOAT"] = [
        {"frame": "motor", "key": {"const": "fwd", "target": "motor"}, "match": {"name": "MOT_TEMP"},
         "fields": {"temperature_c": {"field": "value", "missing": [2.0]}}},
    ]
    mapping["VFR_HUD"].append({"frame": "ambient", "fields": {"temperature_c": {"field": "throttle"}}})
    mapping["BATTERY_STATUS"].append({
        "frame": "pack", "key": {"field": "id", "target": "pack", "map": {"7": "spare", "1": "battery2"}},
        "fields": {"voltage_v": {"field": "voltages", "index": 2, "scale": 0.013, "offset": -0.5, "missing": [65535]},
                   "temperature_c": {"sum": ["temperature"], "scale": 0.01, "missing": [32767]}}})
    mapping["ATTITUDE"] = [{"frame": "airdata", "fields": {"climb_rate": {"sum": ["roll", "pitch"], "missing": [0]},
                                                           "airspeed": {"field": "yaw", "scale": 7.0}}}]
    mapping["SCALED_PRESSURE"].append({"frame": "motor", "key": {"field": "press_diff", "target": "motor",
                                                                 "map": {"0": "aft"}},
                                       "fields": {"temperature_c": {"field": "temperature"}}})
    mapping["HEARTBEAT"].append({"frame": "ambient", "fields": {"temperature_c": {"transform": "armed"}}})
    mapping["SYSTEM_TIME"] = [{"frame": "mission_progress", "fields": {"current_seq": {"field": "time_unix_usec"}}}]
    return mapping


MAPPERS = {
    "default": lambda: FrameMapper(),
    "ungated": lambda: FrameMapper(envelope=None),
    "system 1": lambda: FrameMapper(target_system=1),
    "system 2 component 1": lambda: FrameMapper(target_system=2, target_component=1),
    "custom": lambda: FrameMapper(_custom_mapping()),
}


@pytest.mark.slow
def test_randomly_damaged_logs(tmp_path, columnar_calls, monkeypatch):
    per_message_types = []
    real = frame_columns._message_by_message
    monkeypatch.setattr(frame_columns, "_message_by_message",
                        lambda mapper, plan, *a: per_message_types.append(plan.layout.name) or real(mapper, plan, *a))
    rng = random.Random(18)
    seen = {"reboots": 0, "jumps": 0, "time_rejected": 0, "gated": 0, "unmapped": 0, "foreign": 0, "fallback": 0,
            "other_source": 0, "before_vehicle": 0, "bad_crc": 0}
    for k in range(36):
        path = tmp_path / f"random_{k}.tlog"
        path.write_bytes(random_log(rng, rng.randrange(50, 1500)))
        for name, make in MAPPERS.items():
            _, mapper = mapped_both_ways(path, make)
            stats = mapper.stats
            seen["reboots"] += mapper.clock.reboots
            seen["jumps"] += mapper.clock.jumps
            seen["time_rejected"] += stats.time_rejected
            seen["gated"] += sum(stats.gated.values())
            seen["unmapped"] += sum(stats.unmapped_keys.values())
            seen["foreign"] += len(mapper.foreign_systems)
            seen["fallback"] += mapper.clock.fallback
            seen["other_source"] += stats.other_source
            seen["before_vehicle"] += stats.before_vehicle
        seen["bad_crc"] += scanned_tlog(path).stats.bad_crc
        take_kept_scan(path)
    assert all(seen.values()), seen  # every oddity was met
    assert len(columnar_calls) > 0.8 * 36 * len(MAPPERS)
    assert {"HEARTBEAT", "SYSTEM_TIME", "SCALED_PRESSURE"} <= set(per_message_types)


def test_replay_summary_is_the_paced_replays(tmp_path):
    """The whole replay, by type, and paced (which feeds message by message): the same summary and
    the same frames handed to the consumer."""
    rng = random.Random(7)
    for k in range(4):
        path = tmp_path / f"r{k}.tlog"
        path.write_bytes(random_log(rng, 800))
        got, want = [], []
        by_type = replay.replay_tlog(path, frame_consumer=got.append).to_dict()
        by_message = replay.replay_tlog(path, frame_consumer=want.append, speed=1e12).to_dict()
        for summary in (by_type, by_message):
            summary.pop("elapsed_s"), summary.pop("messages_per_s")
        assert by_type == by_message and repr(got) == repr(want) and got


# --- the pieces ----------------------------------------------------------------------------------

def test_clock_runs_are_its_samples_one_by_one():
    """``on_time_boots`` (consistent runs at once) equals ``on_time_boot`` sample by sample, state included."""
    rng = random.Random(2)
    for _ in range(200):
        one, batch = VehicleClock(), VehicleClock()
        for c in (one, batch):
            c.on_time_boot(100.0, 1.0, 33), c.on_time_boot(100.1, 1.1, 29)
        boot, recv, ids = [], [], []
        b, r = 100.1, 1.1
        for _ in range(rng.randrange(0, 400)):
            r += rng.choice([0.01, 0.1, 1.0])
            b = rng.choice([b + rng.random() * 0.3] * 20 + [b - 1.5, b - 3.0, b + 11.0, rng.random() * 5, 1e6 * rng.random()])
            boot.append(b), recv.append(r), ids.append(rng.choice([33, 29, 2]))
        want = [one.on_time_boot(x, y, z) for x, y, z in zip(boot, recv, ids)]
        times, accepted = batch.on_time_boots(np.array(boot), np.array(recv), np.array(ids))
        assert [t if a else Verdict.REJECTED for t, a in zip(times.tolist(), accepted.tolist())] == want
        assert _clock_state(batch) == _clock_state(one)


def test_payloads_decoded_at_once_are_unpacks():
    """``PayloadLayout.unpack_many`` gives each payload's ``unpack`` (short ones padded, long ones cut)
    for every message of the dialect."""
    rng = random.Random(1)
    for msgid in MESSAGE_CLASSES:
        lay = layout(msgid)
        buf, starts, ends = bytearray(), [], []
        for _ in range(12):
            length = rng.choice([lay.size, rng.randrange(0, lay.size + 1), lay.size + rng.randrange(1, 9)])
            starts.append(len(buf))
            buf += bytes(rng.randrange(256) for _ in range(length))
            ends.append(len(buf))
        rows = lay.unpack_many(np.frombuffer(bytes(buf), dtype=np.uint8), np.array(starts), np.array(ends))
        for row, a, b in zip(rows, starts, ends):
            got = []
            for name in lay.codes:
                value = row[name].tolist()
                got += value if isinstance(value, list) else [value]
            want = [v.rstrip(b"\0") if isinstance(v, bytes) else v for v in lay.unpack(bytes(buf[a:b]))]
            assert repr(got) == repr(want), lay.name
