"""Fly ArduPilot's software in the loop (``../shared/sitl``) beside the service, alone (no other
ground station): the harness of tests/test_sitl_*.py and benchmarks/bench_sitl_live.py.

* ``start_sitl``: one ArduCopter or ArduPlane SITL as a subprocess in its own temporary directory
  (it writes eeprom.bin and logs/ there), its serial0 a UDP client of the service's ``udpin`` port,
  its other ports moved out of the way with ``-I``; stopped by its process id.
* ArduCopter's battery drains only when its frame model has a capacity: ``copter_frame_json``
  writes a JSON frame model (libraries/SITL/SIM_Frame.cpp reads ``battCapacityAh``, ``maxVoltage``,
  ``refBatRes`` ...) given with ``--model quad:FILE.json``; ``SIM_BATT_VOLTAGE`` sets the voltage it
  is plugged in at and, through the simulator's LiPo table (libraries/SITL/SIM_Battery.cpp), its
  starting charge. ``sitl_lipo_soc`` is that table, so the test knows the truth: the starting charge
  less the charge the autopilot counts (``BATTERY_STATUS.current_consumed``; it integrates the
  simulated current, only its percentage starts at 100 % whatever the pack holds).
* The vehicle is commanded through the service's own link (COMMAND_LONG from the service's ids):
  GUIDED, arm, take off.
"""
from __future__ import annotations

import json
import os
import random
import socket
import subprocess
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
SITL = Path(os.environ.get("GCS_PDM_SHARED", REPO / ".." / "shared")) / "sitl"
HOME = "-35.363261,149.165230,584,353"

#: libraries/SITL/SIM_Battery.cpp's table: volts per cell at rest -> charge, %
_SITL_LIPO = np.array([
    (4.173, 100), (4.112, 96.15), (4.085, 92.31), (4.071, 88.46), (4.039, 84.62), (3.987, 80.77),
    (3.943, 76.92), (3.908, 73.08), (3.887, 69.23), (3.854, 65.38), (3.833, 61.54), (3.801, 57.69),
    (3.783, 53.85), (3.742, 50), (3.715, 46.15), (3.679, 42.31), (3.636, 38.46), (3.588, 34.62),
    (3.543, 30.77), (3.503, 26.92), (3.462, 23.08), (3.379, 19.23), (3.296, 15.38), (3.218, 11.54),
    (3.165, 7.69), (3.091, 3.85), (2.977, 2.0)])


def sitl_lipo_soc(voltage: float, max_voltage: float) -> float:
    """The simulator's starting charge (0..1) for a pack set to ``voltage`` whose full voltage is
    ``max_voltage`` (it scales the table's 4.173 V/cell to that)."""
    cell = min(voltage, max_voltage) / max_voltage * _SITL_LIPO[0, 0]
    return float(np.interp(cell, _SITL_LIPO[::-1, 0], _SITL_LIPO[::-1, 1])) / 100.0


def binary(name: str) -> Path:
    return SITL / name


def available(name: str) -> bool:
    return binary(name).is_file() and os.access(binary(name), os.X_OK)


def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _instance_ports_free(n: int) -> bool:
    """SITL instance ``n``'s TCP 5760+10n..5763+10n and RC input UDP 5501+10n are free."""
    for port, kind in [(5760 + 10 * n + k, socket.SOCK_STREAM) for k in range(4)] + [(5501 + 10 * n, socket.SOCK_DGRAM)]:
        with socket.socket(socket.AF_INET, kind) as s:
            try:
                s.bind(("127.0.0.1", port))
            except OSError:
                return False
    return True


def free_instance() -> int:
    for n in random.sample(range(20, 200), 60):
        if _instance_ports_free(n):
            return n
    raise RuntimeError("no free SITL instance number (-I) found")


@dataclass
class CopterPack:
    """The simulated copter's pack: 4S, 5 Ah, plugged in at ``voltage`` (15.60 V: 68 % by the table)."""

    capacity_ah: float = 5.0
    max_voltage: float = 16.8
    voltage: float = 15.6
    resistance_ohm: float = 0.02

    @property
    def start_soc(self) -> float:
        return sitl_lipo_soc(self.voltage, self.max_voltage)


def copter_frame_json(path: Path, pack: CopterPack) -> Path:
    """A JSON frame model: the default quad with this pack (hover ≈ 20 A at 15 V)."""
    path.write_text(json.dumps({"battCapacityAh": pack.capacity_ah, "maxVoltage": pack.max_voltage,
                                "refBatRes": pack.resistance_ohm, "refVoltage": 15.2, "refCurrent": 20.0}))
    return path


#: no stream until a ground station asks: serial0's stream rates at 0 (ArduCopter's default; ArduPlane
#: streams by default). This firmware names them MAV1_* (MAVLink channel 1 = serial0; SR0_* before 4.7)
SILENT_STREAMS = {f"MAV1_{k}": 0 for k in ("RAW_SENS", "EXT_STAT", "RC_CHAN", "RAW_CTRL", "POSITION", "EXTRA1",
                                           "EXTRA2", "EXTRA3", "PARAMS", "ADSB")}


@dataclass
class Sitl:
    proc: subprocess.Popen
    workdir: Path
    log: Path
    extra: dict = field(default_factory=dict)

    def stop(self) -> None:
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(5)

    def output(self) -> str:
        return self.log.read_text(errors="replace")[-3000:] if self.log.exists() else ""


def start_sitl(name: str, workdir: Path, port: int, *, model: str, defaults: list[str], params: dict,
               speedup: float) -> Sitl:
    """``name`` (arducopter | arduplane) in ``workdir``, its serial0 sending to 127.0.0.1:``port``."""
    workdir.mkdir(parents=True, exist_ok=True)
    extra = workdir / "extra.parm"
    extra.write_text("".join(f"{k} {v}\n" for k, v in params.items()))
    log = workdir / "sitl.out"
    cmd = [str(binary(name)), "-I", str(free_instance()), "--model", model, "--speedup", str(speedup),
           "--defaults", ",".join(defaults + [str(extra)]), "--home", HOME,
           "--serial0", f"udpclient:127.0.0.1:{port}", "-w"]
    proc = subprocess.Popen(cmd, cwd=workdir, stdin=subprocess.DEVNULL, stdout=log.open("w"),
                            stderr=subprocess.STDOUT)
    return Sitl(proc, workdir, log)


def wait_for(cond, what: str, timeout: float, sitl: Sitl | None = None, poll: float = 0.1):
    deadline = time.monotonic() + timeout
    while True:
        value = cond()
        if value:
            return value
        if sitl is not None and sitl.proc.poll() is not None:
            raise AssertionError(f"SITL exited ({sitl.proc.returncode}) while waiting for {what}:\n{sitl.output()}")
        if time.monotonic() > deadline:
            raise AssertionError(f"not within {timeout} s: {what}")
        time.sleep(poll)


# --- commanding the vehicle through the service's link ------------------------------------------------

MAV_CMD_DO_SET_MODE, MAV_CMD_COMPONENT_ARM_DISARM, MAV_CMD_NAV_TAKEOFF = 176, 400, 22
COPTER_GUIDED, COPTER_AUTO, PLANE_AUTO = 4, 3, 10


def square_mission(home, side_m: float, alt_m: float, laps: int = 1) -> list:
    """Home, take-off to ``alt_m``, then a square of ``side_m`` about home ``laps`` times."""
    from gcs_pdm import missions as M
    from gcs_pdm.geo import geodetic_from_enu

    lat, lon = home[0], home[1]
    corners = [geodetic_from_enu(e, n, lat, lon) for e, n in ((0, side_m), (side_m, side_m), (side_m, 0), (0, 0))]
    items = [M.waypoint(lat, lon, 0.0, frame=0), M.takeoff(lat, lon, alt_m)]
    items += [M.waypoint(a, o, alt_m) for a, o in corners * laps]
    return M.renumber(items)


class Commander:
    """COMMAND_LONG over the service's link, each retried until the vehicle accepts it."""

    def __init__(self, link):
        self.link = link
        self.acks = link.subscribe({"COMMAND_ACK"}, maxsize=1000)

    def close(self) -> None:
        self.acks.close()

    def command(self, cmd: int, *params: float, timeout: float = 2.0) -> int | None:
        """Send once; the vehicle's MAV_RESULT, or None without an answer within ``timeout`` s."""
        p = list(params) + [0.0] * (7 - len(params))
        self.acks.drain()
        self.link.send(self.link.mav.command_long_encode(self.link.target_system, self.link.target_component, cmd, 0, *p))
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            msg = self.acks.get(timeout=0.1)
            if msg is not None and msg.command == cmd and msg.get_srcSystem() == self.link.target_system:
                return int(msg.result)
        return None

    def until_accepted(self, cmd: int, *params: float, what: str, timeout: float, sitl: Sitl | None = None) -> None:
        last = {"result": None}

        def accepted():
            last["result"] = self.command(cmd, *params)
            if last["result"] != 0:
                time.sleep(0.5)
            return last["result"] == 0

        try:
            wait_for(accepted, what, timeout, sitl, poll=0.0)
        except AssertionError as exc:
            raise AssertionError(f"{exc} (last MAV_RESULT {last['result']})") from None


class BatteryTruth:
    """The autopilot's own BATTERY_STATUS (id 0) as the service's link receives it: the charge drawn
    (``current_consumed``) and ``battery_remaining``, stamped with the service's latest message time."""

    def __init__(self, link, intake):
        self.sub = link.subscribe({"BATTERY_STATUS"}, maxsize=20000)
        self.intake = intake
        self.samples: list[tuple[float, float, int]] = []  # (message time, mAh drawn, remaining %)

    def poll(self) -> None:
        while True:
            msg = self.sub.get(timeout=0)
            if msg is None:
                return
            if msg.id == 0 and msg.current_consumed >= 0 and self.intake.time_s is not None:
                self.samples.append((self.intake.time_s, float(msg.current_consumed), int(msg.battery_remaining)))

    def drawn_ah(self) -> float | None:
        self.poll()
        return self.samples[-1][1] / 1000.0 if self.samples else None

    def close(self) -> None:
        self.sub.close()
