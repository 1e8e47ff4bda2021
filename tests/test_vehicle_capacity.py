"""A provisional description's pack capacity is evidence, never a made-up number: the autopilot's
parameter (asked for live), else the charge drawn against battery_remaining, else "unknown" with the
reason; the simulated vehicle answers the parameter request as ArduPilot does."""
from __future__ import annotations

import queue
from pathlib import Path

import pytest

from gcs_pdm.cli import main
from gcs_pdm.mavlink.dialect import mavlink2
from gcs_pdm.service.vehicle_discovery import VehicleDiscovery
from gcs_pdm.sim.commands import CommandHandler
from gcs_pdm.sim.model import VehicleModel, vehicle_config
from gcs_pdm.vehicle.description import load
from gcs_pdm.vehicle.presets import PRESETS
from gcs_pdm.vehicle.provisional import CapacityUnknown, ProvisionalObserver

STOCK_TLOG = Path(__file__).resolve().parents[1] / ".." / "shared" / "logs" / "arduplane_sitl_stock.tlog"


def _battery(remaining=-1, consumed=-1, mv=16600):
    return {"id": 0, "voltages": [mv] + [65535] * 9, "temperature": 32767, "battery_remaining": remaining,
            "current_consumed": consumed, "current_battery": 1000}


def _booted(**battery) -> ProvisionalObserver:
    obs = ProvisionalObserver()
    obs.observe("HEARTBEAT", {"type": 2, "autopilot": 12})
    for _ in range(5):
        obs.observe("BATTERY_STATUS", _battery(**battery))
    return obs


def test_no_evidence_is_unknown_with_the_reason_and_what_it_disables():
    obs = _booted()
    c = obs.capacity(0)
    assert c.mah is None and "does not report battery_remaining" in c.source
    assert "SoC, time to cut-off and planning need it" in obs.waiting_for()
    with pytest.raises(CapacityUnknown, match="SoC by coulomb counting"):
        obs.derive()


def test_px4_parameter_then_ardupilot_parameter():
    obs = _booted()
    obs.observe("PARAM_VALUE", {"param_id": "BAT1_CAPACITY", "param_value": -1.0})   # PX4: not configured
    assert obs.capacity(0).mah is None
    obs.observe("PARAM_VALUE", {"param_id": "BAT1_CAPACITY", "param_value": 4500.0})
    assert obs.capacity(0).mah == 4500.0 and "BAT1_CAPACITY" in obs.capacity(0).source
    desc, notes = obs.derive()
    assert desc.packs[0].capacity_mah == 4500.0
    assert any("capacity 4500 mAh from the autopilot's BAT1_CAPACITY parameter" in n for n in notes)


def test_the_discharge_measures_it_once_enough_charge_was_used():
    obs = _booted(remaining=95, consumed=100)
    obs.observe("BATTERY_STATUS", _battery(remaining=90, consumed=350))
    assert obs.capacity(0).mah is None and "fallen 5 of the 10" in obs.capacity(0).source
    obs.observe("BATTERY_STATUS", _battery(remaining=85, consumed=600))   # 500 mAh for 10 %
    assert obs.capacity(0).mah == 5000.0 and "charge drawn" in obs.capacity(0).source
    assert obs.waiting_for() is None


class _Msg:
    def __init__(self, kind, fields, src=1):
        self.kind, self.fields, self.src = kind, fields, src

    def get_type(self):
        return self.kind

    def to_dict(self):
        return dict(self.fields)

    def get_srcSystem(self):
        return self.src


class _Sub:
    def __init__(self):
        self.q = queue.Queue()

    def get(self, timeout=None):
        try:
            return self.q.get(timeout=timeout)
        except queue.Empty:
            return None

    def close(self):
        pass


class _Link:
    target_system, target_component = 1, 1

    def __init__(self):
        self.sub, self.sent = _Sub(), []
        self.mav = mavlink2.MAVLink(None, srcSystem=255, srcComponent=190)

    def subscribe(self, types):
        assert "PARAM_VALUE" in types
        return self.sub

    def send(self, msg):
        self.sent.append(msg)


def test_discovery_asks_the_autopilot_and_waits_for_the_answer():
    link = _Link()
    derived = queue.Queue()
    disc = VehicleDiscovery(link, lambda desc, notes: derived.put((desc, notes))).start()
    try:
        link.sub.q.put(_Msg("HEARTBEAT", {"type": 1, "autopilot": 3}))
        for _ in range(6):
            link.sub.q.put(_Msg("BATTERY_STATUS", {**_battery(mv=12600), "id": 0}))
        with pytest.raises(queue.Empty):
            derived.get(timeout=1.0)                       # no capacity yet: not derived, said why
        asked = sorted({m.param_id for m in link.sent if m.get_type() == "PARAM_REQUEST_READ"})
        assert asked == ["BAT1_CAPACITY", "BATT_CAPACITY", "BAT_CAPACITY"]
        assert "the capacity of battery0" in disc.waiting() and "asked the autopilot for BATT_CAPACITY" in disc.waiting()
        link.sub.q.put(_Msg("PARAM_VALUE", {"param_id": "BATT_CAPACITY", "param_value": 3300.0}))
        link.sub.q.put(_Msg("BATTERY_STATUS", {**_battery(mv=12600), "id": 0}))
        desc, notes = derived.get(timeout=5.0)
    finally:
        disc.stop()
    assert desc.packs[0].capacity_mah == 3300.0 and any("BATT_CAPACITY parameter" in n for n in notes)


def test_the_simulated_vehicle_answers_its_battery_capacity():
    handler = CommandHandler(VehicleModel(vehicle_config(PRESETS["plane-3s"])), telemetry=None)
    gcs = mavlink2.MAVLink(None, srcSystem=255, srcComponent=190)
    (reply,) = handler.handle(gcs.param_request_read_encode(1, 1, b"BATT_CAPACITY", -1))
    assert reply.get_type() == "PARAM_VALUE" and reply.param_id == "BATT_CAPACITY" and reply.param_value == 3300.0
    assert handler.handle(gcs.param_request_read_encode(1, 1, b"BATT2_CAPACITY", -1)) == []   # no second monitor
    assert handler.handle(gcs.param_request_read_encode(1, 1, b"BAT1_CAPACITY", -1)) == []    # not ArduPilot's
    hexa = CommandHandler(VehicleModel(vehicle_config(PRESETS["hex-6s"])), telemetry=None)
    (reply,) = hexa.handle(gcs.param_request_read_encode(1, 1, b"BATT2_CAPACITY", -1))
    assert reply.param_value == 10000.0


@pytest.mark.skipif(not STOCK_TLOG.is_file(), reason="needs ../shared/logs")
def test_init_takes_the_users_capacity(tmp_path, capsys):
    out = tmp_path / "v.toml"
    assert main(["vehicle", "init", "--from", str(STOCK_TLOG), "--capacity-mah", "0=2200", "--out", str(out)]) == 0
    assert load(out).packs[0].capacity_mah == 2200.0 and "as given by the user" in capsys.readouterr().err
    assert main(["vehicle", "init", "--from", str(STOCK_TLOG), "--capacity-mah", "0=lots", "--out",
                 str(tmp_path / "w.toml")]) == 2  # an input error (docs/cli.md)
    assert "expected [ID=]MAH" in capsys.readouterr().err
