"""Mission upload through MAVProxy (``--out`` forwarding), as an operator's setup has it.

The simulated vehicle talks to MAVProxy's master port; MAVProxy forwards to our link with
``--out``, and forwards what we send back to the vehicle, while its own modules (wp, param, ...)
talk to the vehicle too. The upload must behave as on a direct link: accepted, read back equal,
and MAVProxy's own mission traffic must not be taken for ours.

MAVProxy (test extra) pulls in GUI-adjacent packages (opencv, matplotlib); it may live in its own
virtualenv: the test looks for ``mavproxy.py`` on PATH, then in ``$GCS_PDM_MAVPROXY`` and
``/work/venv-mavproxy/bin``.
"""
from __future__ import annotations

import dataclasses
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest

from gcs_pdm.mavlink.autopilots import missions_equivalent
from gcs_pdm.mavlink.connection import Link, LinkConfig
from gcs_pdm.mavlink.mission_client import MissionClient
from gcs_pdm.missions import as_sent, same_items
from gcs_pdm.sim.model import SimConfig
from gcs_pdm.sim.routes import mission_from_enu
from gcs_pdm.sim.vehicle import SimulatedVehicle

sys.path.insert(0, str(Path(__file__).parent / "mavlink"))  # shared helpers; tests/ is not a package
from mavlink_peers import free_udp_port  # noqa: E402


def _mavproxy() -> str | None:
    # beside this interpreter first: the test extra installs it into the running venv, which need
    # not be on PATH (``/path/to/venv/bin/python -m pytest`` without activating it)
    for candidate in (str(Path(sys.executable).parent / "mavproxy.py"), shutil.which("mavproxy.py"),
                      os.environ.get("GCS_PDM_MAVPROXY")):
        if candidate and Path(candidate).is_file():
            return candidate
    return None


MAVPROXY = _mavproxy()
pytestmark = [
    pytest.mark.skipif(MAVPROXY is None, reason="MAVProxy not installed (pip install MAVProxy; test extra), "
                       "nor found on PATH or in $GCS_PDM_MAVPROXY"),
    pytest.mark.slow,
]

MISSION = mission_from_enu([(800, 0, 100), (800, 800, 120), (0, 800, 100), (-300, 0, 60)])


@pytest.fixture
def through_mavproxy(tmp_path):
    master, out = free_udp_port(), free_udp_port()
    proc = subprocess.Popen(
        [MAVPROXY, f"--master=udpin:127.0.0.1:{master}", f"--out=udpout:127.0.0.1:{out}", "--daemon",
         "--non-interactive", f"--state-basedir={tmp_path}", "--nowait"],
        stdin=subprocess.DEVNULL, stdout=(tmp_path / "mavproxy.out").open("w"), stderr=subprocess.STDOUT,
        cwd=tmp_path)
    try:
        with Link(LinkConfig(url=f"udpin:127.0.0.1:{out}")) as link:
            vehicle = SimulatedVehicle(SimConfig(seed=5, autostart=False), f"udpout:127.0.0.1:{master}", speedup=1.0)
            with vehicle:
                link.wait_for_vehicle(30)
                yield link, vehicle, proc
    finally:
        proc.terminate()
        try:
            proc.wait(10)
        except subprocess.TimeoutExpired:
            proc.kill()
        if proc.returncode not in (0, -15, None):
            print((tmp_path / "mavproxy.out").read_text()[-2000:])


def _no_current(items):
    return [dataclasses.replace(as_sent(i), current=0) for i in items]


def test_upload_download_and_set_current_through_mavproxy(through_mavproxy):
    link, vehicle, proc = through_mavproxy
    assert proc.poll() is None, "MAVProxy exited"
    client = MissionClient(link)
    stats = client.upload(MISSION)
    assert stats.attempts >= 1
    back = client.download()
    assert same_items(_no_current(back), _no_current(MISSION))
    assert missions_equivalent(MISSION, back, 3).equivalent  # the sim says MAV_AUTOPILOT_ARDUPILOTMEGA
    client.set_current(2)
    deadline = time.monotonic() + 5
    while vehicle.core.model.current_seq != 2 and time.monotonic() < deadline:
        time.sleep(0.05)
    assert vehicle.core.model.current_seq == 2
    # a second upload replaces the first (MAVProxy's own wp module saw the change and stays quiet)
    shorter = MISSION[:3]
    client.upload(shorter)
    assert same_items(_no_current(client.download()), _no_current(shorter))
