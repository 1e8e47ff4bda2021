"""Shared by the browser tests and scripts/make_console_screenshots.py: ``gcs-pdm serve`` and
``gcs-pdm sim`` as real processes on free loopback ports, and Debian's Chromium under Playwright.

Nothing is downloaded: the browser is the system's ``chromium`` (``CHROMIUM`` overrides the path).
"""
from __future__ import annotations

import json
import os
import secrets
import shutil
import socket
import subprocess
import sys
import time
import urllib.request
from dataclasses import dataclass, field
from pathlib import Path
from urllib.parse import urlsplit

REPO = Path(__file__).resolve().parents[2]
CHROMIUM_ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
                 "--disable-component-update", "--disable-sync", "--no-first-run"]


def chromium_path() -> str:
    path = os.environ.get("CHROMIUM") or shutil.which("chromium") or "/usr/bin/chromium"
    if not Path(path).exists():
        raise RuntimeError("no Chromium: install Debian's 'chromium' package (.ci/run does) or set CHROMIUM")
    return path


def free_port(kind: int = socket.SOCK_STREAM) -> int:
    with socket.socket(socket.AF_INET, kind) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _env() -> dict[str, str]:
    env = dict(os.environ)
    # the processes run this checkout's code, whatever is installed
    env["PYTHONPATH"] = os.pathsep.join([str(REPO), *filter(None, [env.get("PYTHONPATH")])])
    return env


@dataclass
class Service:
    """One ``gcs-pdm serve`` process (advise policy, the Table III objectives)."""

    folder: Path
    http_port: int = field(default_factory=free_port)
    udp_port: int = field(default_factory=lambda: free_port(socket.SOCK_DGRAM))
    token: str = field(default_factory=lambda: secrets.token_urlsafe(24))
    proc: subprocess.Popen | None = None
    tryout: dict = field(default_factory=dict)
    extra_env: dict = field(default_factory=dict)

    @property
    def url(self) -> str:
        return f"http://127.0.0.1:{self.http_port}"

    @property
    def host(self) -> str:
        return urlsplit(self.url).netloc

    def start(self, timeout_s: float = 30.0) -> "Service":
        from gcs_pdm.service.demo import export_tryout

        self.folder.mkdir(parents=True, exist_ok=True)
        self.tryout = self.tryout or export_tryout(self.folder)
        env = _env() | {"GCS_PDM_API_TOKEN": self.token} | self.extra_env
        log = open(self.folder / "serve.log", "ab")
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "gcs_pdm.cli", "serve", "--mavlink", f"udpin:127.0.0.1:{self.udp_port}",
             "--http", f"127.0.0.1:{self.http_port}", "--policy", "advise", "--data-dir", str(self.folder / "data"),
             "--vehicle", "edge540", "--objectives", self.tryout["objectives"]], env=env, stdout=log, stderr=subprocess.STDOUT)
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if self.proc.poll() is not None:
                raise RuntimeError(f"serve exited {self.proc.returncode}: {(self.folder / 'serve.log').read_text()[-2000:]}")
            try:
                with urllib.request.urlopen(self.url + "/health", timeout=1.0) as r:
                    if json.loads(r.read())["status"]:
                        return self
            except OSError:
                time.sleep(0.2)
        raise RuntimeError("serve did not answer /health in time")

    def stop(self) -> None:
        _stop(self.proc)

    def get(self, path: str):
        with urllib.request.urlopen(self.url + path, timeout=5.0) as r:
            return json.loads(r.read())

    def send(self, method: str, path: str, body: dict):
        req = urllib.request.Request(self.url + path, method=method, data=json.dumps(body).encode(),
                                     headers={"Content-Type": "application/json", "Authorization": f"Bearer {self.token}"})
        with urllib.request.urlopen(req, timeout=10.0) as r:
            return json.loads(r.read())


def motor_fit_request(save_as: str, starts: int = 2) -> dict:
    """A small motor fit on three recorded simulator flights (about 15 s with 2 starts)."""
    flights = REPO / "fixtures" / "flights"
    return {"component": "motor", "save_as": save_as,
            "flights": {"train": [{"path": str(flights / "learn_01.tlog")}],
                        "validation": [{"path": str(flights / "learn_02.tlog")}],
                        "test": [{"path": str(flights / "learn_03.tlog")}]},
            "settings": {"search": {"starts": starts, "sa_generations": 6, "lm_max_nfev": 4}, "workers": 1}}


def battery_fit_request(save_as: str) -> dict:
    """A small paper-variant battery fit on PyBaMM flights whose test flight (chen2020_11) starts below the
    one training flight's start and flies hotter and harder: the fit warns about both (a few seconds)."""
    flights = REPO / "fixtures" / "pybamm" / "Chen2020"
    return {"component": "battery", "packs": ["LLF20"], "save_as": save_as,
            "flights": {"train": [{"path": str(flights / "chen2020_02.parquet")}],
                        "validation": [{"path": str(flights / "chen2020_02.parquet")}],
                        "test": [{"path": str(flights / "chen2020_11.parquet")}]},
            "settings": {"model": "paper", "search": {"starts": 2, "sa_generations": 4, "lm_max_nfev": 4}, "workers": 1}}


@dataclass
class Sim:
    """``gcs-pdm sim`` flying the Table III mission with the demo's motor fault."""

    service: Service
    speedup: float = 40.0
    proc: subprocess.Popen | None = None

    def start(self) -> "Sim":
        from gcs_pdm.service.demo import demo_telemetry

        t = self.service.tryout
        # the demo's thinner telemetry: what the estimator needs, light enough for a busy machine
        rates = [a for name, hz in demo_telemetry().rates_hz.items() for a in ("--rate", f"{name}={hz:g}")]
        log = open(self.service.folder / "sim.log", "ab")
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "gcs_pdm.cli", "sim", "--connect", f"udpout:127.0.0.1:{self.service.udp_port}",
             "--speedup", str(self.speedup), "--mission", t["mission"], "--fault", t["fault"], "--start-delay", "1",
             *rates],
            env=_env(), stdout=log, stderr=subprocess.STDOUT)
        return self

    def stop(self) -> None:
        _stop(self.proc)


def _stop(proc: subprocess.Popen | None) -> None:
    if proc is None or proc.poll() is not None:
        return
    proc.terminate()
    try:
        proc.wait(timeout=10)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait(timeout=5)


class RequestLog:
    """Every URL the page asks for (Playwright's request event), to prove it calls no other host."""

    def __init__(self, page) -> None:
        self.urls: list[str] = []
        page.on("request", lambda req: self.urls.append(req.url))

    def foreign(self, host: str) -> list[str]:
        return [u for u in self.urls if urlsplit(u).scheme not in ("data", "blob") and urlsplit(u).netloc != host]


#: Playwright's default wait for an expectation (5 s) is shorter than a page's first fetches on a
#: loaded 2-core machine running the suite on every core (the packs page's first row missed it
#: twice at load 17-22); an expectation that holds returns at once, so a longer wait costs nothing
EXPECT_TIMEOUT_MS = 20_000


def launch(playwright):
    from playwright.sync_api import expect

    expect.set_options(timeout=EXPECT_TIMEOUT_MS)
    return playwright.chromium.launch(executable_path=chromium_path(), args=CHROMIUM_ARGS)
