"""A provisional vehicle description from the first telemetry, when the user gives none.

Pure core: ``ProvisionalObserver.observe(name, fields)`` folds decoded MAVLink messages (message
name and a field dict, as ``msg.to_dict()`` gives them, or as the link layer decodes them live) and
``derive()`` turns what it saw into a description plus the notes that say what was guessed:

- airframe from the vehicle's HEARTBEAT ``type`` (MAV_TYPE): fixed wing, or a multirotor whose
  rotor count is the type's (quad 4, hexa 6, octo 8, tri 3, coaxial 2);
- packs from the BATTERY_STATUS ids seen; cells in series from the highest pack voltage seen,
  the smallest count with at most 4.35 V per cell at the median of its first five readings (right for a 6S pack between 3.63 and 4.35 V/cell,
  a 3S one between 2.9 and 4.35);
  capacity from the autopilot's capacity parameter when a PARAM_VALUE gave it (ArduPilot
  ``BATT_CAPACITY``/``BATTn_CAPACITY``, PX4 ``BATn_CAPACITY``), else from the charge drawn against
  the reported remaining percentage when it fell by 10 % or more, otherwise *unknown*: no number is
  made up; ``waiting_for`` and ``derive`` say why (the pack model — SoC by coulomb counting, time to
  cut-off, planning — needs it);
- the chemistry from the rest voltage at boot (``models.chemistry``): a LiPo unless the pack rests
  above a LiPo's highest rested cell (4.25 V), then a LiHV (4.35 V full); never a full-cell voltage
  above what the chemistry allows (a pack that holds more voltage under load than the chemistry's
  model is said in the notes; the estimator learns its resistance and curve in flight);
- cells from the per-cell voltages when BATTERY_STATUS carries them (each entry one cell);
- motors from the ESC_TELEMETRY_* indices that carried any non-zero value, with the readings
  that were non-zero (current, rpm, temperature);
- the airframe's aerodynamic figures and the mass from the matching preset (said in the notes).

A VTOL (MAV_TYPE 19-24) is described as its fixed-wing cruise, said in the notes.

The I/O shells feed it: ``gcs_pdm.mavlink.provisional_vehicle.observe_tlog`` a tlog file,
``gcs_pdm.logs.provisional_vehicle`` an autopilot's own log (DataFlash, ULog) turned into the same
messages, the service the live link.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Iterable, Mapping

from gcs_pdm.models.chemistry import CHEMISTRIES, chemistry_of_rest_voltage
from gcs_pdm.vehicle.description import VehicleDescription, VehicleError, from_dict

#: MAV_TYPE -> rotor count, for the multirotor types
MULTIROTOR_ROTORS = {2: 4, 3: 2, 13: 6, 14: 8, 15: 3}
MAV_TYPE_FIXED_WING = 1
#: VTOL MAV_TYPEs (tailsitters, tiltrotor, standard VTOL, tiltwing): their cruise is a fixed wing's
MAV_TYPES_VTOL = {19, 20, 21, 22, 23, 24}
#: HEARTBEATs that are not the vehicle: GCS (6), onboard controller (18), gimbal (26), ADSB (27), ...
_NOT_A_VEHICLE_TYPES = {6, 18, 26, 27, 30}
_MAV_AUTOPILOT_INVALID = 8
#: the highest resting voltage of a cell: a full LiHV (4.35 V); a LiPo rests at 4.2, ArduPilot SITL's at 4.24
MAX_CELL_VOLTAGE = 4.35
_UINT16_MAX = 65535
#: a BATTERY_STATUS voltages entry that is one cell's, mV (a pack voltage in one entry is above)
_CELL_MV = (2000, 4600)
_INT16_MAX = 32767
_ESC_MESSAGES = {"ESC_TELEMETRY_1_TO_4": 0, "ESC_TELEMETRY_5_TO_8": 4, "ESC_TELEMETRY_9_TO_12": 8,
                 "ESC_TELEMETRY_13_TO_16": 12}


#: the fall of battery_remaining (percentage points) over which charge drawn measures the capacity
CAPACITY_MIN_FALL_PCT = 10


class CapacityUnknown(VehicleError):
    """A pack's capacity has no evidence yet (no autopilot parameter, not enough discharge)."""


@dataclass(frozen=True)
class Capacity:
    """A pack's capacity and where it came from; ``mah`` None: unknown, ``source`` says why."""

    mah: float | None
    source: str


#: readings whose median is the pack's voltage at boot (robust to one noisy sample)
FIRST_READINGS = 5
#: cells of slack on the count: a pack at exactly 4.35 V/cell plus sensor noise is not one cell more
CELL_COUNT_SLACK = 0.02
#: loaded readings kept per pack for the stiffness check (pack voltage, current, reported SoC)
LOADED_READINGS = 400
#: a reading is "loaded" from this current on, A
LOADED_CURRENT_A = 2.0
#: per-cell gap (observed over modelled voltage under load) from which the full-cell voltage is raised
STIFFNESS_GAP_CELL_V = 0.02


@dataclass
class _PackSeen:
    max_voltage: float = 0.0
    first_voltages: list = field(default_factory=list)
    temperature_reported: bool = False
    first_remaining: int | None = None
    first_consumed_mah: float | None = None
    capacity_estimate_mah: float | None = None
    #: how far battery_remaining has fallen so far, percentage points (-1: never reported)
    remaining_fall: int = -1
    frames: int = 0
    #: (voltage V, current A, the autopilot's remaining fraction) under load
    loaded: list = field(default_factory=list)
    #: cells the BATTERY_STATUS voltages array counts, when it carries one cell per entry (0: it
    #: does not — a pack voltage in the first entry, as ArduPilot sends it without cell monitoring)
    cells_reported: int = 0


@dataclass
class _EscSeen:
    current: bool = False
    rpm: bool = False
    temperature: bool = False
    frames: int = 0


@dataclass
class ProvisionalObserver:
    """Folds messages; ``derive()`` may be called at any time (e.g. once every pack has reported)."""

    mav_type: int | None = None
    packs: dict[int, _PackSeen] = field(default_factory=dict)
    escs: dict[int, _EscSeen] = field(default_factory=dict)
    messages: int = 0
    #: the autopilot's parameters seen (PARAM_VALUE): name -> value
    parameters: dict[str, float] = field(default_factory=dict)
    #: where the airframe type came from, for the notes (default: the HEARTBEAT)
    airframe_source: str | None = None

    def observe(self, name: str, fields: Mapping[str, Any]) -> None:
        self.messages += 1
        if name == "HEARTBEAT":
            if (self.mav_type is None and fields.get("type") not in _NOT_A_VEHICLE_TYPES
                    and fields.get("autopilot") != _MAV_AUTOPILOT_INVALID):
                self.mav_type = int(fields["type"])
        elif name == "BATTERY_STATUS":
            self._battery(fields)
        elif name in _ESC_MESSAGES:
            self._esc(_ESC_MESSAGES[name], fields)
        elif name == "PARAM_VALUE" and fields.get("param_id") is not None:
            self.parameters[str(fields["param_id"])] = float(fields.get("param_value", math.nan))

    def capacity_parameter(self, pack_id: int) -> tuple[str, float] | None:
        """The pack's capacity (mAh) as the autopilot is configured: (parameter, value), or None."""
        for n, _ in self._capacity_names(pack_id):
            v = self.parameters.get(n)
            if v is not None and math.isfinite(v) and v > 0:  # 0 / -1: not configured
                return n, v
        return None

    def capacity(self, pack_id: int) -> Capacity:
        """The pack's capacity from evidence: the autopilot's parameter, else the charge drawn against
        the fall of battery_remaining, else unknown with the reason."""
        configured = self.capacity_parameter(pack_id)
        if configured:
            return Capacity(configured[1], f"from the autopilot's {configured[0]} parameter")
        seen = self.packs.get(pack_id, _PackSeen())
        if seen.capacity_estimate_mah:
            return Capacity(round(seen.capacity_estimate_mah, -1),
                            "from the charge drawn (current_consumed) against the fall of battery_remaining")
        names = "/".join(n for n, _ in self._capacity_names(pack_id)[:2])
        if seen.remaining_fall < 0:
            discharge = "the pack does not report battery_remaining and current_consumed"
        else:
            discharge = (f"battery_remaining has fallen {seen.remaining_fall} of the {CAPACITY_MIN_FALL_PCT} "
                         f"percentage points needed to measure it from the charge drawn")
        return Capacity(None, f"unknown: no {names} parameter seen, and {discharge}")

    @staticmethod
    def _capacity_names(pack_id: int) -> list[tuple[str, str]]:
        ardupilot = "BATT_CAPACITY" if pack_id == 0 else f"BATT{pack_id + 1}_CAPACITY"
        return ([(ardupilot, "ArduPilot"), (f"BAT{pack_id + 1}_CAPACITY", "PX4")]
                + ([("BAT_CAPACITY", "PX4")] if pack_id == 0 else []))

    def capacity_parameter_names(self) -> list[str]:
        """The parameters a GCS may ask the autopilot for, to learn the capacities of the packs seen."""
        return [n for i in sorted(self.packs) for n, _ in self._capacity_names(i)]

    def _battery(self, f: Mapping[str, Any]) -> None:
        seen = self.packs.setdefault(int(f["id"]), _PackSeen())
        seen.frames += 1
        cells = [c for c in [*(f.get("voltages") or ()), *(f.get("voltages_ext") or ())] if c != 0 and c != _UINT16_MAX]
        volts = sum(cells) / 1000.0
        if len(cells) > 1 and all(_CELL_MV[0] <= c <= _CELL_MV[1] for c in cells):
            seen.cells_reported = max(seen.cells_reported, len(cells))
        if cells:
            seen.max_voltage = max(seen.max_voltage, volts)
            if len(seen.first_voltages) < FIRST_READINGS:
                seen.first_voltages.append(volts)
        temp = f.get("temperature")
        if temp is not None and temp != _INT16_MAX:
            seen.temperature_reported = True
        remaining, consumed = f.get("battery_remaining"), f.get("current_consumed")
        current = f.get("current_battery")
        if (cells and current is not None and current >= LOADED_CURRENT_A * 100 and remaining is not None
                and 0 < remaining <= 100 and len(seen.loaded) < LOADED_READINGS):
            seen.loaded.append((volts, current / 100.0, remaining / 100.0))
        if remaining is None or consumed is None or remaining < 0 or consumed < 0:
            return
        if seen.first_remaining is None:
            seen.first_remaining, seen.first_consumed_mah = int(remaining), float(consumed)
        seen.remaining_fall = max(seen.remaining_fall, seen.first_remaining - int(remaining))
        if seen.first_remaining - remaining >= CAPACITY_MIN_FALL_PCT:
            drawn = float(consumed) - seen.first_consumed_mah
            if drawn > 0:
                seen.capacity_estimate_mah = drawn / ((seen.first_remaining - remaining) / 100.0)

    def observe_batteries(self, columns: Mapping[str, Any]) -> None:
        """Fold many BATTERY_STATUS messages at once, given as numpy columns in arrival order (field
        -> array, ``voltages``/``voltages_ext`` one row per message; what
        ``gcs_pdm.mavlink.tlog.tlog_message_columns`` gives): the same as :meth:`observe` of each
        in turn, computed per pack over whole arrays."""
        import numpy as np

        ids = np.asarray(columns["id"]).astype(np.int64)
        self.messages += int(ids.size)
        cells = np.concatenate([np.asarray(columns["voltages"]), np.asarray(columns["voltages_ext"])],
                               axis=1).astype(np.int64)
        valid = (cells != 0) & (cells != _UINT16_MAX)
        has_cells = valid.any(axis=1)
        volts = np.where(valid, cells, 0).sum(axis=1) / 1000.0
        per_cell = (valid.sum(axis=1) > 1) & np.all(~valid | ((cells >= _CELL_MV[0]) & (cells <= _CELL_MV[1])), axis=1)
        temperature = np.asarray(columns["temperature"]).astype(np.int64)
        current = np.asarray(columns["current_battery"]).astype(np.int64)
        remaining = np.asarray(columns["battery_remaining"]).astype(np.int64)
        consumed = np.asarray(columns["current_consumed"]).astype(np.int64)
        loaded = has_cells & (current >= LOADED_CURRENT_A * 100) & (remaining > 0) & (remaining <= 100)
        discharge = (remaining >= 0) & (consumed >= 0)
        for pack_id in dict.fromkeys(ids.tolist()):  # in order of first appearance, as observe() adds them
            mine = ids == pack_id
            seen = self.packs.setdefault(pack_id, _PackSeen())
            seen.frames += int(mine.sum())
            if (mine & per_cell).any():
                seen.cells_reported = max(seen.cells_reported, int(valid[mine & per_cell].sum(axis=1).max()))
            reported = volts[mine & has_cells]
            if reported.size:
                seen.max_voltage = max(seen.max_voltage, float(reported.max()))
                room = FIRST_READINGS - len(seen.first_voltages)
                if room > 0:
                    seen.first_voltages.extend(reported[:room].tolist())
            if (temperature[mine] != _INT16_MAX).any():
                seen.temperature_reported = True
            room = LOADED_READINGS - len(seen.loaded)
            if room > 0:
                rows = mine & loaded
                seen.loaded.extend(zip(volts[rows][:room].tolist(), (current[rows][:room] / 100.0).tolist(),
                                       (remaining[rows][:room] / 100.0).tolist()))
            rows = mine & discharge
            if not rows.any():
                continue
            rem, con = remaining[rows], consumed[rows]
            if seen.first_remaining is None:
                seen.first_remaining, seen.first_consumed_mah = int(rem[0]), float(con[0])
            fall = seen.first_remaining - rem
            seen.remaining_fall = max(seen.remaining_fall, int(fall.max()))
            drawn = con - seen.first_consumed_mah
            measured = np.flatnonzero((fall >= CAPACITY_MIN_FALL_PCT) & (drawn > 0))
            if measured.size:  # the last message that measures it, as observe() leaves it
                last = measured[-1]
                seen.capacity_estimate_mah = float(drawn[last] / (fall[last] / 100.0))

    def _esc(self, base: int, f: Mapping[str, Any]) -> None:
        columns = [f.get(key) or (0, 0, 0, 0) for key in ("current", "rpm", "temperature", "voltage", "count")]
        for k in range(4):
            current, rpm, temperature, voltage, count = (column[k] for column in columns)
            if not (current or rpm or temperature or voltage or count):
                continue
            seen = self.escs.setdefault(base + k, _EscSeen())
            seen.frames += 1
            seen.current |= bool(current)
            seen.rpm |= bool(rpm)
            seen.temperature |= bool(temperature)

    def waiting_for(self) -> str | None:
        """What a derivation still waits for (None: settled, derive now). Settled = the vehicle's
        HEARTBEAT seen and every pack that reported a voltage has given its first readings (the
        boot voltage is their median); by then a vehicle with ESC telemetry has sent it too."""
        if self.mav_type is None:
            return "the vehicle's HEARTBEAT"
        packs = {i: p for i, p in sorted(self.packs.items()) if p.max_voltage > 0}
        if not packs:
            return "a BATTERY_STATUS with a voltage"
        short = [f"battery{i} ({len(p.first_voltages)} of {FIRST_READINGS} readings)"
                 for i, p in packs.items() if len(p.first_voltages) < FIRST_READINGS]
        if short:
            return "the first voltage readings of " + ", ".join(short)
        unknown = [f"battery{i} ({c.source}; SoC, time to cut-off and planning need it)"
                   for i in packs if (c := self.capacity(i)).mah is None]
        return "the capacity of " + ", ".join(unknown) if unknown else None

    # ---- the description ----------------------------------------------------------------------
    def derive(self, name: str = "provisional", capacities: Mapping[int, float] | None = None,
               ) -> tuple[VehicleDescription, list[str]]:
        """The provisional description and the notes on what was guessed (raise if nothing to go on;
        ``CapacityUnknown`` if a pack's capacity has no evidence and ``capacities`` — the user's,
        by BATTERY_STATUS id, in mAh — does not give it)."""
        from gcs_pdm.vehicle.presets import PRESETS

        notes: list[str] = []
        if self.mav_type is None:
            raise VehicleError("no vehicle HEARTBEAT seen: cannot tell the airframe")
        if self.mav_type == MAV_TYPE_FIXED_WING or self.mav_type in MAV_TYPES_VTOL:
            base = PRESETS["plane-3s"].to_dict()
            n_rotors = 1
            if self.mav_type in MAV_TYPES_VTOL:
                notes.append(f"MAV_TYPE {self.mav_type} is a VTOL: described as its fixed-wing cruise; the lift "
                             f"motors and hover are not modelled")
        elif self.mav_type in MULTIROTOR_ROTORS:
            base = PRESETS["quad-4s"].to_dict()
            n_rotors = MULTIROTOR_ROTORS[self.mav_type]
        else:
            raise VehicleError(f"HEARTBEAT type {self.mav_type} (MAV_TYPE) is neither a fixed wing nor a "
                               f"multirotor: write the description by hand (docs/vehicles.md)")
        notes.append(f"airframe from {self.airframe_source or 'HEARTBEAT type ' + str(self.mav_type)}; its figures and the mass "
                     f"({base['mass_kg']} kg) are the {base['name']} preset's: correct them")
        packs_seen = {i: p for i, p in sorted(self.packs.items()) if p.max_voltage > 0}
        if not packs_seen:
            raise VehicleError("no BATTERY_STATUS with a voltage seen: cannot tell the packs")
        packs = []
        for i, seen in packs_seen.items():
            boot_v = sorted(seen.first_voltages)[len(seen.first_voltages) // 2]
            cells = seen.cells_reported or max(1, math.ceil(boot_v / MAX_CELL_VOLTAGE - CELL_COUNT_SLACK))
            pack = {"name": f"battery{i}", "mavlink_battery_id": i, "cells_series": cells,
                    "reports_temperature": seen.temperature_reported}
            if seen.cells_reported:
                notes.append(f"pack battery{i}: {cells} cells from the per-cell voltages it reports")
            capacity = (Capacity(float(capacities[i]), "as given by the user") if capacities and i in capacities
                        else self.capacity(i))
            if capacity.mah is None:
                raise CapacityUnknown(f"pack battery{i}: capacity {capacity.source}; the pack model (SoC by "
                                      f"coulomb counting, time to cut-off, planning) needs it: give it (e.g. "
                                      f"`gcs-pdm vehicle init --from LOG --capacity-mah {i}=MAH`, or capacity_mah "
                                      f"in a description) or set the autopilot's capacity parameter")
            pack["capacity_mah"] = capacity.mah
            how = capacity.source
            rest_cell_v = boot_v / cells
            chem = chemistry_of_rest_voltage(rest_cell_v)
            if chem != "lipo":
                pack["chemistry"] = chem
                notes.append(f"pack battery{i}: rests at {rest_cell_v:.3f} V/cell at boot, above a LiPo's "
                             f"{CHEMISTRIES['lipo'].max_rest_cell_v} V: a {chem} pack "
                             f"({CHEMISTRIES[chem].full_cell_v} V full)")
            elif rest_cell_v > CHEMISTRIES["lihv"].max_rest_cell_v:
                notes.append(f"pack battery{i}: rests at {rest_cell_v:.3f} V/cell at boot, above any chemistry's "
                             f"full cell: check its cell count and voltage sensor")
            notes.append(f"pack battery{i}: {cells} cells from {boot_v:.2f} V at boot, "
                         f"capacity {pack['capacity_mah']:.0f} mAh {how}, chemistry-default parameters"
                         + ("" if seen.temperature_reported else "; temperature not reported (estimated)"))
            packs.append(pack)
        escs = {i: e for i, e in sorted(self.escs.items())}
        if escs:
            motors = [{"name": f"esc{i}", "esc_index": i,
                       "readings": {"current": e.current, "rpm": e.rpm, "temperature": e.temperature},
                       "values": base["motors"][0]["values"]} for i, e in escs.items()]
            notes.append(f"motors from the ESC indices that carried data: {', '.join(map(str, escs))}")
        else:
            motors = [{"name": f"motor{k + 1}", "esc_index": k,
                       "readings": {"current": False, "rpm": False, "temperature": False},
                       "values": base["motors"][0]["values"]} for k in range(n_rotors)]
            notes.append(f"no ESC telemetry: {n_rotors} motor(s) assumed, none of them reporting")
        bus = {"packs": [p["name"] for p in packs], "arrangement": "parallel" if len(packs) > 1 else "series",
               "motors": [m["name"] for m in motors]}
        if len(packs) > 1:
            notes.append("several packs: assumed in parallel on one bus feeding every motor")
        data = {**base, "name": name, "provisional": True, "packs": packs, "motors": motors, "buses": [bus]}
        _raise_full_cell_voltage(data, [seen.loaded for seen in packs_seen.values()], notes)
        data["description"] = "derived from telemetry: " + "; ".join(notes)
        return from_dict(data), notes


def _raise_full_cell_voltage(data: dict, loaded: list[list], notes: list[str]) -> None:
    """A pack that holds more voltage under load than its model at the SoC the autopilot reports:
    raise its full-cell voltage by the median gap per cell (the model's voltage rises one for one
    with it) — never above the full cell its chemistry allows (issue 29: a 4.50 V/cell LiPo was
    derived for a SITL pack whose voltage does not sag at all) — and say so. The model's loaded
    voltage is the kernel's (R–C pairs settled at the reading's current)."""
    if not any(len(samples) >= FIRST_READINGS for samples in loaded):
        return
    import numpy as np

    from gcs_pdm.models import kernel
    from gcs_pdm.vehicle.model_inputs import model_inputs

    desc = from_dict(data)
    matrix = model_inputs(desc).pack_matrix
    for k, samples in enumerate(loaded):
        if len(samples) < FIRST_READINGS:
            continue
        v, i, soc = (np.array(c) for c in zip(*samples))
        rows = np.repeat(matrix[k][None], len(v), axis=0)
        modelled = kernel.terminal_voltage(rows, kernel.initial_pack_state(rows, soc, 25.0, i))
        pack = data["packs"][k]
        gap = float(np.median(v - modelled)) / pack["cells_series"]
        if gap <= STIFFNESS_GAP_CELL_V:
            continue
        spec = desc.packs[k]
        allowed = CHEMISTRIES[spec.chemistry].full_cell_v if spec.chemistry in CHEMISTRIES else spec.full_cell_v
        raised = min(allowed, round(spec.full_cell_v + gap + 0.005, 2))
        if raised > spec.full_cell_v:
            pack["full_cell_voltage"] = raised
        notes.append(f"pack {pack['name']}: held {gap:.2f} V/cell more under load than the chemistry default "
                     f"at the SoC the autopilot reported (stiffer than that model)"
                     + (f": full-cell voltage raised to {raised:.2f} V, the {spec.chemistry} limit"
                        if raised > spec.full_cell_v else f"; its full cell stays the {spec.chemistry}'s "
                                                         f"{spec.full_cell_v:.2f} V")
                     + "; the estimator learns its resistance and curve in flight, a fit gives a real model "
                       "(docs/vehicles.md)")


def derive_provisional(messages: Iterable[tuple[str, Mapping[str, Any]]], name: str = "provisional",
                       capacities: Mapping[int, float] | None = None) -> tuple[VehicleDescription, list[str]]:
    """Pure: (message name, fields) pairs -> (description, notes); ``capacities`` as in ``derive``."""
    obs = ProvisionalObserver()
    for msg_name, fields in messages:
        obs.observe(msg_name, fields)
    return obs.derive(name, capacities)


#: the messages ``ProvisionalObserver.observe`` folds: what a reader of a recorded flight decodes for it
OBSERVED_MESSAGES = ("HEARTBEAT", "BATTERY_STATUS", "PARAM_VALUE", *_ESC_MESSAGES)
