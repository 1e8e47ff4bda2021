"""Time drift on an unsigned link (issue 34): one packet a second from a sender with the vehicle's
ids, each 9.9 s ahead of the vehicle's time, used to run message time at 9.9x real time (in 60 s the
estimated SoC fell 0.15 where the truth fell 0.02, and a +594 s offset stayed). The vehicle clock now
holds a forward step against receive time: the step is not followed by the vehicle's next sample,
so message time stays the vehicle's, and the unfollowed steps are warned about within seconds."""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from gcs_pdm.frames import MotorFrame, PackFrame
from gcs_pdm.mavlink import connection
from gcs_pdm.mavlink.clock import Verdict, VehicleClock
from gcs_pdm.mavlink.connection import Link, LinkConfig
from gcs_pdm.mavlink.dialect import mavlink2

sys.path.insert(0, str(Path(__file__).parent / "mavlink"))  # shared helpers; tests/ is not a package
from mavlink_builders import PacketFactory  # noqa: E402

DRIFT_S = 9.9
BOOT_S = 100.0  # the vehicle's time_boot at the start of the test


def test_steps_ahead_that_the_vehicle_does_not_follow_never_move_message_time_and_are_warned():
    clock = VehicleClock()
    attacker_s = 0.0
    warned_at = None
    latest = None
    for k in range(600):  # 60 s: the vehicle's timed stream at 10 Hz, the attacker's packet once a second
        recv = 10.0 + k * 0.1
        vehicle_s = BOOT_S + k * 0.1
        latest = clock.on_time_boot(vehicle_s, recv, msgid=33 if k % 2 else 29)
        if k > 1:
            assert latest == pytest.approx(vehicle_s)  # every vehicle sample keeps its own time
        if k % 10 == 5:
            attacker_s = max(attacker_s, vehicle_s) + DRIFT_S
            assert clock.on_time_boot(attacker_s, recv + 0.01, msgid=33) is Verdict.REJECTED
        assert clock.now is None or clock.now <= vehicle_s + 1e-9  # message time never ran ahead of the vehicle's
        if warned_at is None and clock.spoof_suspected:
            warned_at = recv - 10.0
    print(f"drift +{DRIFT_S} s/s: warned after {warned_at} s of receive time")
    assert warned_at is not None and warned_at <= 10.0, warned_at
    report = clock.to_dict()
    assert report["spoof_suspected"] and "another sender uses the vehicle's ids" in report["spoof_reason"]
    assert report["unfollowed_steps"] == 60 and report["jumps"] == 0 and report["reboots"] == 0


def test_a_vehicle_faster_than_real_time_and_a_short_outage_are_not_steps_to_hold():
    clock = VehicleClock()
    for k in range(3000):  # a simulator at 60x: 0.1 s of its time every 1.7 ms of receive time
        assert clock.on_time_boot(BOOT_S + k * 0.1, k * 0.1 / 60.0, msgid=33) is not Verdict.REJECTED or k == 0
    recv = 3000 * 0.1 / 60.0 + 6.0  # a 6-s outage: the vehicle's time moved as much as the receive time
    assert clock.on_time_boot(BOOT_S + 300.0 + 6.0, recv, msgid=33) == pytest.approx(BOOT_S + 306.0)
    assert clock.rejected == 0 and not clock.spoof_suspected


class FakeTime:
    def __init__(self):
        self.now = 0.0

    def monotonic(self) -> float:
        return self.now

    def time(self) -> float:
        return 1.7e9 + self.now


def _packets_of(frames_at_t, factory: PacketFactory, t: float) -> list[bytes]:
    """One synthetic-flight instant as the vehicle sends it: its timed position first, then the
    pack and motor readings (untimed messages, stamped by the vehicle clock)."""
    out = [factory.position(int((BOOT_S + t) * 1000))]
    motors = {f.motor: f for f in frames_at_t if isinstance(f, MotorFrame)}
    if motors:
        order = ("fwd", "aft")
        out.append(factory.esc([int(round(motors[m].current_a * 100)) if m in motors else 0 for m in order] + [0, 0],
                               [int(motors[m].rpm) if m in motors else 0 for m in order] + [0, 0],
                               [max(0, int(motors[m].temperature_c)) if m in motors else 0 for m in order] + [0, 0]))
    for f in frames_at_t:
        if isinstance(f, PackFrame):
            pack_id = ("LLF20", "ULA20", "LRF40", "URA40").index(f.pack)
            out.append(factory.battery(pack_id, [int(round(f.voltage_v * 1000))], int(round(f.current_a * 100)),
                                       int(round(f.temperature_c * 100))))
    return out


def test_a_drifting_sender_leaves_the_soc_estimate_within_003_over_60_s(monkeypatch):
    from gcs_pdm.estimation.estimator import StateEstimator
    from gcs_pdm.estimation.synthetic import fly_synthetic
    from gcs_pdm.models.params import default_set

    params = default_set()
    flight = fly_synthetic(params, np.random.default_rng(3), duration_s=70.0, initial_soc=0.9)
    fake = FakeTime()
    monkeypatch.setattr(connection, "time", fake)
    link = Link(LinkConfig(url="udpin:127.0.0.1:1", heartbeat_hz=0))  # never opened: packets injected
    est = StateEstimator(params)
    frames = []
    link.add_frame_listener(frames.append)
    vehicle, attacker = PacketFactory(1, 1, numbered=True), PacketFactory(1, 1, numbered=True)

    def send(factory, packet, at):
        fake.now = at
        msg = mavlink2.MAVLink(None).decode(bytearray(packet))
        msg._timestamp = fake.time()
        link.handle_message(msg)

    by_time: dict[float, list] = {}
    for f in flight.frames:
        by_time.setdefault(f.time_s, []).append(f)
    attacker_s, next_attack = 0.0, 1.0
    send(vehicle, vehicle.heartbeat(), 0.0)
    for t in sorted(by_time):
        for packet in _packets_of(by_time[t], vehicle, t):
            send(vehicle, packet, t)
        if t >= next_attack:  # once a second: the vehicle's time seen so far + 9.9 s
            attacker_s = max(attacker_s, BOOT_S + t) + DRIFT_S
            send(attacker, attacker.position(int(attacker_s * 1000)), t + 0.01)
            next_attack += 1.0
        if t % 1.0 < 0.25:
            send(vehicle, vehicle.heartbeat(), t)
    for frame in frames:
        est.consume(frame)
    e = est.estimate()
    k = min(int(np.searchsorted(flight.time_s, flight.time_s[-1])), flight.time_s.size - 1)
    err = np.abs(e.soc - flight.soc[k])
    print(f"SoC error after {flight.time_s[-1]:.1f} s under +{DRIFT_S} s/s drift: max {float(err.max()):.4f}; "
          f"message time offset {e.time_s - BOOT_S - flight.time_s[-1]:+.2f} s")
    assert flight.time_s[-1] >= 60.0
    assert float(err.max()) <= 0.03, (e.soc, flight.soc[k])
    assert e.time_s - BOOT_S == pytest.approx(flight.time_s[-1], abs=0.6)  # no offset left behind
    assert link.trust_report()["clock"]["spoof_suspected"]


def test_small_steps_ahead_that_run_the_clock_fast_are_noticed_by_its_rate():
    """A sender whose steps stay within what is taken at once (1.9 s ahead of message time, once a
    second) runs message time at about 2x: the steps are not held, the rate gives it away."""
    clock = VehicleClock()
    suspected_at = None
    for k in range(1200):  # 120 s; the first 40 s without the sender set the vehicle's pace
        recv = k * 0.1
        clock.on_time_boot(BOOT_S + k * 0.1, recv, msgid=33 if k % 2 else 29)
        if k >= 400 and k % 10 == 5:
            clock.on_time_boot(clock.now + 1.9, recv + 0.01, msgid=33)
        if suspected_at is None and clock.to_dict()["spoof_suspected"]:
            suspected_at = recv - 40.0
    report = clock.to_dict()
    assert report["rate"]["baseline"] == pytest.approx(1.0, abs=0.02)
    assert suspected_at is not None and suspected_at <= 20.0, suspected_at
    assert "ran at" in report["spoof_reason"]


def test_a_fast_simulator_catching_up_with_its_clock_raises_no_rate_suspicion():
    """A simulator 60x faster than real time that falls behind its wall clock and catches up (150x
    for a while) is not judged by its pace: only a vehicle on real time is."""
    clock = VehicleClock()
    recv = 0.0
    for k in range(60_000):  # samples every 0.1 s of its time
        recv += 0.1 / (150.0 if 30_000 <= k < 45_000 else 60.0)
        clock.on_time_boot(BOOT_S + k * 0.1, recv, msgid=33)
    report = clock.to_dict()
    assert report["rate"]["baseline"] == pytest.approx(60.0, rel=0.01)
    assert not report["spoof_suspected"] and report["rate"]["off_windows"] == 0
