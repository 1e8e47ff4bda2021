"""Configuration (defaults < file < environment < overrides, errors naming the field) and `serve`."""
from __future__ import annotations

import json
import socket
import threading
import time

import httpx
import pytest

from gcs_pdm.service.config import ConfigError, ServiceConfig, load_config


def test_defaults_are_documented_values():
    c = load_config(env={})
    assert c.mavlink_url == "udpin:127.0.0.1:14551" and c.target_system == 1 and c.source_system != 255 and c.http_host == "127.0.0.1" and c.http_port == 8000
    assert c.policy == "advise" and c.parameter_set == "paper_si"  # advise: the operator approves (issue 12)
    assert str(c.database).endswith("gcs_pdm.sqlite3")
    # every field has a default, so an empty file is a valid configuration
    assert all(not f.is_required() for f in ServiceConfig.model_fields.values())


def test_file_then_env_then_overrides(tmp_path):
    toml = tmp_path / "svc.toml"
    toml.write_text('[service]\npolicy = "advise"\nhttp_port = 9001\nparticles = 12\n')
    c = load_config(toml, env={})
    assert (c.policy, c.http_port, c.particles) == ("advise", 9001, 12)
    c = load_config(toml, env={"GCS_PDM_HTTP_PORT": "9100", "GCS_PDM_POLICY": "auto"})
    assert (c.policy, c.http_port) == ("auto", 9100)
    c = load_config(toml, env={"GCS_PDM_HTTP_PORT": "9100"}, http_port=9200)
    assert c.http_port == 9200
    js = tmp_path / "svc.json"
    js.write_text(json.dumps({"db_path": str(tmp_path / "x.db")}))
    assert load_config(env={"GCS_PDM_CONFIG": str(js)}).database == tmp_path / "x.db"


@pytest.mark.parametrize("env,field", [
    ({"GCS_PDM_POLICY": "sometimes"}, "policy"),
    ({"GCS_PDM_HTTP_PORT": "eighty"}, "http_port"),
    ({"GCS_PDM_PARTICLES": "0"}, "particles"),
    ({"GCS_PDM_PLANNER": "magic"}, "planner"),
])
def test_bad_values_name_the_field(env, field):
    with pytest.raises(ConfigError, match=f"^{field}:"):
        load_config(env=env)


def test_every_configurable_planner_runs(monkeypatch):
    """The names the config accepts are exactly the ones the planner adapter can run."""
    import importlib
    import typing

    from gcs_pdm.service.adapters import run_planner

    # modules, not the package's re-exported functions of the same names
    exact, local_search, particle_filter = (importlib.import_module(f"gcs_pdm.planning.{m}")
                                            for m in ("exact", "local_search", "particle_filter"))

    ran = []
    monkeypatch.setattr(local_search, "pf_local_search", lambda sim, **kw: ran.append("pfls"))
    monkeypatch.setattr(particle_filter, "particle_filter", lambda sim, **kw: ran.append("pf"))
    monkeypatch.setattr(exact, "exact_search", lambda sim, **kw: ran.append("exact"))
    names = typing.get_args(ServiceConfig.model_fields["planner"].annotation)
    assert {"auto", "pfls", "pf", "exact"} <= set(names)  # the names docs/service.md lists
    for name in names:
        assert load_config(env={"GCS_PDM_PLANNER": name}).planner == name
        run_planner(name, sim=None, particles=3, seed=0, deadline_s=1.0)
    assert ran == ["pfls" if n in ("auto", "stronger", "pfls") else n for n in names]


def test_bad_files(tmp_path):
    with pytest.raises(ConfigError, match="nope.toml"):
        load_config(tmp_path / "nope.toml", env={})
    bad = tmp_path / "bad.toml"
    bad.write_text("policy = \n")
    with pytest.raises(ConfigError, match="bad.toml"):
        load_config(bad, env={})
    unknown = tmp_path / "unknown.toml"
    unknown.write_text('polcy = "auto"\n')
    with pytest.raises(ConfigError, match="^polcy:"):
        load_config(unknown, env={})


def _free_port(kind=socket.SOCK_STREAM) -> int:
    with socket.socket(socket.AF_INET, kind) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_serve_starts_answers_and_stops(tmp_path):
    from gcs_pdm.service.server import serve

    port = _free_port()
    cfg = load_config(env={}, data_dir=str(tmp_path), http_port=port, api_token="config-test-token-0123",
                      mavlink_url=f"udpin:127.0.0.1:{_free_port(socket.SOCK_DGRAM)}")
    stop = threading.Event()
    rc = {}
    t = threading.Thread(target=lambda: rc.setdefault("rc", serve(cfg, stop=stop)), daemon=True)
    t.start()
    try:
        deadline = time.monotonic() + 20
        while True:
            try:
                h = httpx.get(f"http://127.0.0.1:{port}/health", timeout=1).json()
                break
            except httpx.HTTPError:
                if time.monotonic() > deadline:
                    raise
                time.sleep(0.1)
        assert h["status"] == "ok" and h["link_connected"] is False
        r = httpx.put(f"http://127.0.0.1:{port}/policy", json={"policy": "advise"},
                      headers={"Authorization": "Bearer config-test-token-0123"})
        assert r.json() == {"policy": "advise"}
        tl = httpx.get(f"http://127.0.0.1:{port}/tlogs").json()
        assert len(tl) == 1 and tl[0]["note"] == "live session"
    finally:
        stop.set()
        t.join(15)
    assert rc.get("rc") == 0


def test_process_environment_is_read_and_booleans_parse(tmp_path, monkeypatch):
    toml = tmp_path / "svc.toml"
    toml.write_text('record_tlog = true\nconfirm_download = true\n')
    monkeypatch.setenv("GCS_PDM_RECORD_TLOG", "false")
    monkeypatch.setenv("GCS_PDM_CONFIG", str(toml))
    c = load_config()  # env=None: os.environ, and the file it names
    assert c.record_tlog is False and c.confirm_download is True
    # a call with its own environment sees none of the process's
    assert load_config(env={}).record_tlog is True


def test_the_planner_registry_is_the_one_list():
    """The CLI's --planner choices and the service's planner values both come from planners.REGISTRY."""
    import argparse
    import typing

    from gcs_pdm.planning import cli as planning_cli
    from gcs_pdm.planning.planners import ALIASES, REGISTRY, SERVICE_PLANNERS, resolve

    parser = argparse.ArgumentParser()
    planning_cli.register(parser.add_subparsers())
    plan = next(a for a in parser._subparsers._group_actions[0].choices["plan"]._actions if a.dest == "planner")
    assert set(plan.choices) == set(REGISTRY) | set(ALIASES)
    assert typing.get_args(ServiceConfig.model_fields["planner"].annotation) == SERVICE_PLANNERS
    assert "brute" in REGISTRY and "brute" not in SERVICE_PLANNERS  # too slow for a live replan
    assert resolve("auto") is resolve("stronger") is REGISTRY["pfls"]
    with pytest.raises(ValueError, match="^planner:"):
        resolve("magic")
