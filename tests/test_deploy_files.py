"""The shipped deployment files agree with the code's safe defaults (issue 12)."""
from __future__ import annotations

import re
from pathlib import Path

from gcs_pdm.mavlink.connection import DEFAULT_URL
import pytest

from gcs_pdm.service.config import ConfigError, ServiceConfig, load_config

DEPLOY = Path(__file__).resolve().parents[1] / "deploy"


def test_shipped_config_loads_and_its_token_is_a_refusable_placeholder():
    # The service refuses tokens shorter than 16 characters and known placeholders: the shipped
    # one must be one of those, so a forgotten edit can never become a working credential.
    with pytest.raises(ConfigError, match="^api_token: is a known placeholder"):
        load_config(DEPLOY / "gcs-pdm.toml", env={})
    assert "refuse" in (DEPLOY / "gcs-pdm.toml").read_text()
    # the environment's token (as the Dockerfile and compose pass it) replaces the placeholder
    cfg = load_config(DEPLOY / "gcs-pdm.toml", env={"GCS_PDM_API_TOKEN": "a-real-random-token-0123"})
    assert cfg.mavlink_url == DEFAULT_URL == ServiceConfig.model_fields["mavlink_url"].default
    assert cfg.source_system != 255 and cfg.target_system == 1


def test_containers_publish_on_loopback_only():
    docker = (DEPLOY / "Dockerfile").read_text()
    compose = (DEPLOY / "compose.yaml").read_text()
    published = re.findall(r"(?:^|\s)-p\s+(\d[^\s\\]*)", docker) + re.findall(r'^\s*-\s*"([^"]+)"', compose, re.M)
    assert published, "no published ports found"
    assert all(p.startswith("127.0.0.1:") for p in published), published
    assert "change-me" not in docker.lower() and "change-me" not in compose.lower()
    port = DEFAULT_URL.rsplit(":", 1)[1]
    assert f"udpin:0.0.0.0:{port}" in docker and f"udpout:gcs-pdm:{port}" in compose

