"""`gcs-pdm serve` start-up failures: one clear line on stderr, a non-zero exit within seconds, no
traceback, and no port left held (issue 12, "Process behaviour")."""
from __future__ import annotations

import os
import socket
import subprocess
import sys
import time

import pytest

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def _free(kind: int) -> int:
    with socket.socket(socket.AF_INET, kind) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _serve(tmp_path, *args, env_extra=None) -> tuple[subprocess.CompletedProcess, float]:
    env = dict(os.environ, GCS_PDM_API_TOKEN="a-test-token-long-enough", **(env_extra or {}))
    env.pop("GCS_PDM_CONFIG", None)
    started = time.monotonic()
    out = subprocess.run([sys.executable, "-m", "gcs_pdm.cli", "serve", "--data-dir", str(tmp_path / "data"), *args],
                         capture_output=True, text=True, cwd=REPO, env=env, timeout=60)
    return out, time.monotonic() - started


def _assert_one_clear_line(out: subprocess.CompletedProcess, expected: str) -> None:
    assert out.returncode == 2, (out.returncode, out.stderr)
    assert "Traceback" not in out.stderr, out.stderr
    lines = [ln for ln in out.stderr.splitlines() if ln.startswith("gcs-pdm serve:")]
    assert len(lines) == 1 and expected in lines[0], out.stderr


def _port_is_free(port: int, kind: int) -> bool:
    with socket.socket(socket.AF_INET, kind) as s:
        try:
            s.bind(("127.0.0.1", port))
            return True
        except OSError:
            return False


def test_http_port_taken(tmp_path):
    udp = _free(socket.SOCK_DGRAM)
    with socket.socket() as held:
        held.bind(("127.0.0.1", 0))
        held.listen()
        http = held.getsockname()[1]
        out, took = _serve(tmp_path, "--http", f"127.0.0.1:{http}", "--mavlink", f"udpin:127.0.0.1:{udp}")
    _assert_one_clear_line(out, f"HTTP port 127.0.0.1:{http} is already in use")
    assert took < 30 and _port_is_free(udp, socket.SOCK_DGRAM)


def test_mavlink_port_taken(tmp_path):
    http = _free(socket.SOCK_STREAM)
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as held:
        held.bind(("127.0.0.1", 0))
        udp = held.getsockname()[1]
        out, took = _serve(tmp_path, "--http", f"127.0.0.1:{http}", "--mavlink", f"udpin:127.0.0.1:{udp}")
    _assert_one_clear_line(out, f"udpin:127.0.0.1:{udp} is already in use")
    assert took < 30 and _port_is_free(http, socket.SOCK_STREAM)


@pytest.mark.parametrize("args, env, expected", [
    (["--mavlink", "udpin:nowhere"], None, "not understood"),
    (["--mavlink", "/dev/ttyNOSUCH7"], None, "serial device /dev/ttyNOSUCH7 does not exist"),
    (["--config", "/nonexistent/gcs-pdm.toml"], None, "config file /nonexistent/gcs-pdm.toml"),
    ([], {"GCS_PDM_SIGNING_KEY_FILE": "/nonexistent/key"}, "signing key file /nonexistent/key"),
    (["--objectives", "/nonexistent/objectives.json"], None, "objectives file /nonexistent/objectives.json"),
    (["--target-system", "lots"], None, None),  # argparse's own usage error
])
def test_bad_settings(tmp_path, args, env, expected):
    extra = [] if any(a == "--mavlink" for a in args) else ["--mavlink", f"udpin:127.0.0.1:{_free(socket.SOCK_DGRAM)}"]
    out, took = _serve(tmp_path, "--http", f"127.0.0.1:{_free(socket.SOCK_STREAM)}", *extra, *args, env_extra=env)
    if expected is None:
        assert out.returncode == 2 and "Traceback" not in out.stderr and "neither a system id" in out.stderr
    else:
        _assert_one_clear_line(out, expected)
    assert took < 30
