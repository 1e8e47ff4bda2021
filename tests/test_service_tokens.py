"""The API token (issue 12): known placeholders and short tokens are refused at start-up with one
line naming the field; an unset token is generated and logged; ``advise`` is the default policy."""
from __future__ import annotations

import logging
import os
import subprocess
import sys
from pathlib import Path

import pytest

from gcs_pdm.service.config import MIN_TOKEN_CHARS, ConfigError, load_config
from gcs_pdm.service.runtime import Service

REPO = Path(__file__).resolve().parents[1]


@pytest.mark.parametrize("token", ["CHANGE-ME", "changeme", "change_me", "Change-Me", "token", "TOKEN", "secret",
                                   "password", "test", "Testing", "your-api-token", "short", "a" * (MIN_TOKEN_CHARS - 1)])
def test_placeholder_and_short_tokens_are_refused_naming_the_field(token):
    for source in ({"env": {"GCS_PDM_API_TOKEN": token}}, {"env": {}, "api_token": token}):
        with pytest.raises(ConfigError, match=r"^api_token: is (a known placeholder|shorter than 16 characters)"):
            load_config(**source)


def test_a_long_random_token_is_accepted_and_an_unset_one_generated(tmp_path, caplog):
    assert load_config(env={"GCS_PDM_API_TOKEN": "x7Qp-2mZr_91LkWd"}).api_token == "x7Qp-2mZr_91LkWd"
    assert load_config(env={}).api_token is None
    with caplog.at_level(logging.WARNING, logger="gcs_pdm.service.runtime"):
        svc = Service(load_config(env={}, data_dir=str(tmp_path)))
    try:
        assert len(svc.token) >= MIN_TOKEN_CHARS and svc.token in caplog.text
    finally:
        svc.close()


def test_serve_refuses_the_shipped_placeholder_in_one_line(tmp_path):
    env = {k: v for k, v in os.environ.items() if not k.startswith("GCS_PDM_")}
    out = subprocess.run([sys.executable, "-m", "gcs_pdm.cli", "serve", "--config", str(REPO / "deploy" / "gcs-pdm.toml"),
                          "--data-dir", str(tmp_path / "data"), "--http", "127.0.0.1:0",
                          "--mavlink", "udpin:127.0.0.1:0"],
                         capture_output=True, text=True, cwd=REPO, env=env, timeout=60)
    assert out.returncode == 2 and "Traceback" not in out.stderr, out.stderr
    lines = out.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("gcs-pdm serve: error: api_token: is a known placeholder"), out.stderr
    assert not (tmp_path / "data").exists()  # refused before anything was opened


def test_advise_is_the_default_policy_and_the_demo_chooses_auto():
    import inspect

    from gcs_pdm.service.demo import run_demo

    assert load_config(env={}).policy == "advise"
    assert inspect.signature(run_demo).parameters["policy"].default == "auto"


@pytest.mark.parametrize("token,why", [
    (" " * 16, "fewer than 8 distinct characters"), ("a" * 16, "fewer than 8 distinct characters"),
    ("abababababababab", "fewer than 8 distinct characters"), ("password12345678", "a common password"),
    ("P@ssw0rd!2024-x#", "a common password"), ("letmein-letmein-99", "a common password"),
    ("qwerty_123456789", "a common password")])
def test_weak_tokens_are_refused_naming_why(token, why):
    """Issue 34: 16 spaces, aaaaaaaaaaaaaaaa and password12345678 were accepted."""
    with pytest.raises(ConfigError, match=f"^api_token: (is|has) {why}"):
        load_config(env={}, api_token=token)


@pytest.mark.parametrize("token", ["x7Qp-2mZr_91LkWd", "trust-test-token-0123456", "correct-horse-battery-staple-42"])
def test_random_and_passphrase_tokens_are_accepted(token):
    assert load_config(env={}, api_token=token).api_token == token
