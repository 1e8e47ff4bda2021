"""The provisional description's column fold of BATTERY_STATUS equals folding each message in turn."""
from __future__ import annotations

import random

import numpy as np

from gcs_pdm.mavlink.tlog import TlogWriter, tlog_message_columns, tlog_message_dicts
from gcs_pdm.vehicle.provisional import ProvisionalObserver
from gcs_pdm.mavlink.dialect import mavlink2


def _battery_fields(rng: random.Random) -> dict:
    cells = rng.choice([[4100] * 3 + [65535] * 7, [0] * 10, [65535] * 10, [rng.randrange(3000, 4400)] * 4 + [65535] * 6])
    return {"id": rng.choice([0, 1, 2, 7]), "voltages": cells, "voltages_ext": rng.choice([[0] * 4, [4000, 0, 0, 0]]),
            "temperature": rng.choice([32767, 2500, -500]), "current_battery": rng.choice([-1, 0, 150, 200, 2500]),
            "battery_remaining": rng.choice([-1, 0, 100, 101, rng.randrange(0, 101)]),
            "current_consumed": rng.choice([-1, rng.randrange(0, 5000)])}


def test_column_fold_equals_message_fold():
    rng = random.Random(3)
    measured = 0
    for _ in range(20):
        messages = [_battery_fields(rng) for _ in range(rng.randrange(0, 900))]
        one_by_one = ProvisionalObserver()
        for fields in messages:
            one_by_one.observe("BATTERY_STATUS", fields)
        columns = {k: np.array([m[k] for m in messages], dtype=np.int64).reshape(len(messages), -1)
                   for k in ("voltages", "voltages_ext")}
        columns.update({k: np.array([m[k] for m in messages], dtype=np.int64)
                        for k in ("id", "temperature", "current_battery", "battery_remaining", "current_consumed")})
        at_once = ProvisionalObserver()
        at_once.observe_batteries(columns)
        assert at_once == one_by_one
        measured += sum(1 for p in one_by_one.packs.values() if p.capacity_estimate_mah)
    assert measured  # the capacity-from-discharge branch was exercised


def test_columns_from_a_tlog_are_the_decoded_fields(tmp_path):
    rng = random.Random(5)
    mav = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
    path = tmp_path / "b.tlog"
    with TlogWriter(path) as w:
        for k in range(200):
            f = _battery_fields(rng)
            msg = mavlink2.MAVLink_battery_status_message(
                f["id"], 0, 0, f["temperature"], f["voltages"], f["current_battery"], f["current_consumed"], -1,
                f["battery_remaining"], 0, 0, f["voltages_ext"], 0, 0)
            w.write(msg.pack(mav), 1000.0 + k)
    decoded = [fields for _name, fields in tlog_message_dicts(path, ["BATTERY_STATUS"])]
    columns = tlog_message_columns(path, "BATTERY_STATUS")
    assert len(decoded) == len(columns["id"]) == 200
    for name in ("id", "temperature", "current_battery", "battery_remaining", "current_consumed", "voltages",
                 "voltages_ext"):
        assert [np.atleast_1d(v).tolist() for v in columns[name]] == [np.atleast_1d(d[name]).tolist() for d in decoded]
