"""Schemathesis against the app's own OpenAPI (issue 12): generated requests, valid and invalid,
with the bearer token, must never get a 5xx, a status code the OpenAPI does not list, or an
error body outside the documented error model. In-process over ASGI, no MAVLink link."""
from __future__ import annotations

import pytest

schemathesis = pytest.importorskip("schemathesis")  # the ``test`` extra installs it
from hypothesis import HealthCheck, settings  # noqa: E402
from schemathesis.checks import not_a_server_error  # noqa: E402
from schemathesis.specs.openapi.checks import (  # noqa: E402
    content_type_conformance,
    response_schema_conformance,
    status_code_conformance,
)

from gcs_pdm.service.api import create_app  # noqa: E402
from gcs_pdm.service.config import load_config  # noqa: E402
from gcs_pdm.service.runtime import Service  # noqa: E402

TOKEN = "openapi-fuzz-token-0123456789"
CHECKS = (not_a_server_error, status_code_conformance, content_type_conformance, response_schema_conformance)


@pytest.fixture(scope="module")
def api_schema(tmp_path_factory):
    svc = Service(load_config(env={}, data_dir=str(tmp_path_factory.mktemp("openapi")), api_token=TOKEN,
                              max_upload_bytes=64_000, max_upload_rows=100))
    yield schemathesis.openapi.from_asgi("/openapi.json", create_app(svc))
    svc.close()


schema = schemathesis.pytest.from_fixture("api_schema")


# /events is a Server-Sent Events stream that stays open: it has its own tests (test_service_api.py)
@schema.exclude(path="/events").parametrize()
@settings(max_examples=12, deadline=None, derandomize=True, database=None,
          suppress_health_check=list(HealthCheck))
@pytest.mark.slow
def test_no_5xx_and_no_undocumented_status(case):
    for headers in ({"Authorization": f"Bearer {TOKEN}"}, {}):
        response = case.call(headers=headers)
        case.validate_response(response, checks=CHECKS)


def test_every_error_response_is_documented_with_the_error_model(api_schema):
    spec = api_schema.raw_schema
    assert "ErrorOut" in spec["components"]["schemas"]
    for path, ops in spec["paths"].items():
        for method, op in ops.items():
            codes = {int(c) for c in op["responses"] if c != "default"}
            mutating = method in ("post", "put", "delete")
            if mutating:
                assert 401 in codes, (method, path)
            if "{" in path:
                assert 422 in codes and (404 in codes or path == "/parameter-sets/{name}"), (method, path, codes)
            for code in codes - {200, 201, 202}:
                ref = op["responses"][str(code)]["content"]["application/json"]["schema"]["$ref"]
                assert ref.endswith("/ErrorOut"), (method, path, code, ref)
