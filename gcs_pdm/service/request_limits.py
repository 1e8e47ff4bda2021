"""What a request may cost before any route sees it, and what an error answer may carry.

* :class:`JsonBodyGuard` (ASGI middleware): a request body other than an upload to ``/files`` is at
  most ``max_json_bytes`` — refused with 413 at once from ``Content-Length``, or as soon as the
  streamed bytes pass it, before it is parsed and before the token is checked (a 1 GB body without
  a token took 3.1 GB of memory before its 401). A JSON body with a number JSON cannot hold (NaN,
  Infinity, or one that overflows a double, such as 1e309) is refused with 422 here, so no route
  stores or computes with one.
* :func:`validation_errors`: FastAPI's 422 details without the input echoed back beyond a short
  excerpt (a 422 used to return a 200 MB input whole).
* :func:`storage_failure`: a disk or database that cannot take a write (ENOSPC, EDQUOT, EROFS, EIO;
  SQLite's "database or disk is full") becomes 507 with the reason, instead of a 500.
"""
from __future__ import annotations

import errno
import json
import math
import sqlite3
from typing import Any

#: characters of a rejected input shown back in a 422 (enough to find it, never the input itself)
EXCERPT_CHARS = 80
#: methods whose body is read
BODY_METHODS = frozenset({"POST", "PUT", "PATCH", "DELETE"})
#: errno values that mean the data directory cannot take writes now
STORAGE_ERRNOS = {errno.ENOSPC: "disk full", errno.EDQUOT: "disk quota exceeded", errno.EROFS: "read-only file system",
                  errno.EIO: "disk input/output error"}


class NonFiniteNumber(ValueError):
    pass


def _finite_float(text: str) -> float:
    value = float(text)
    if not math.isfinite(value):
        raise NonFiniteNumber(f"number {text[:EXCERPT_CHARS]} is out of range (not a finite double)")
    return value


def _no_constant(name: str):
    raise NonFiniteNumber(f"{name} is not a JSON number")


def non_finite_problem(body: bytes) -> str | None:
    """Why a JSON body holds a number that is not finite, or None (a body that is not JSON at all is
    left to the route's own parser, which answers 422 in FastAPI's shape)."""
    try:
        json.loads(body, parse_float=_finite_float, parse_constant=_no_constant)
    except NonFiniteNumber as exc:
        return str(exc)
    except (ValueError, RecursionError):
        return None
    return None


def _too_large(limit: int) -> dict:
    return {"detail": f"request body larger than the limit of {limit} bytes (max_json_bytes)"}


class JsonBodyGuard:
    """Bounds every request body except ``skip_path``'s (uploads have their own limit) by
    ``max_bytes()`` and refuses JSON bodies with non-finite numbers; see the module's doc."""

    def __init__(self, app, max_bytes, skip_path: str = "/files"):
        self.app = app
        self.max_bytes = max_bytes  # a callable: the service's configured limit
        self.skip_path = skip_path

    async def __call__(self, scope, receive, send):
        if scope["type"] != "http" or scope["method"] not in BODY_METHODS or scope["path"] == self.skip_path:
            await self.app(scope, receive, send)
            return
        from starlette.responses import JSONResponse

        limit = int(self.max_bytes())
        headers = dict(scope["headers"])
        length = headers.get(b"content-length", b"")
        if length.isdigit() and int(length) > limit:
            await JSONResponse(_too_large(limit), status_code=413)(scope, receive, send)
            return
        # read the body here (at most ``limit`` bytes are ever held), then hand it on whole
        chunks, size, more = [], 0, True
        while more:
            message = await receive()
            if message["type"] != "http.request":  # the client went away
                await self.app(scope, _replay([], message, receive), send)
                return
            chunk = message.get("body", b"")
            size += len(chunk)
            if size > limit:
                await JSONResponse(_too_large(limit), status_code=413)(scope, receive, send)
                return
            chunks.append(chunk)
            more = message.get("more_body", False)
        body = b"".join(chunks)
        if body and b"json" in headers.get(b"content-type", b"application/json").lower():
            problem = non_finite_problem(body)
            if problem is not None:
                await JSONResponse({"detail": [{"loc": ["body"], "msg": problem, "type": "value_error"}]},
                                   status_code=422)(scope, receive, send)
                return
        await self.app(scope, _replay(body, None, receive), send)


def _replay(body, first, receive):
    sent = False

    async def replay():
        nonlocal sent
        if not sent:
            sent = True
            if first is not None:
                return first
            return {"type": "http.request", "body": body, "more_body": False}
        return await receive()

    return replay


def excerpt(value: Any) -> Any:
    """A rejected input as far as it may be shown back: small scalars as they are, anything else
    as the start of its text."""
    if value is None or isinstance(value, (bool, int, float)) and len(repr(value)) <= EXCERPT_CHARS:
        return value
    text = value if isinstance(value, str) else (
        value.decode("utf-8", "replace") if isinstance(value, (bytes, bytearray)) else repr(value))
    return text if len(text) <= EXCERPT_CHARS else text[:EXCERPT_CHARS] + f"… ({len(text)} characters)"


def validation_errors(errors) -> list[dict]:
    """FastAPI's validation errors as ``{loc, msg, type}`` plus an excerpt of the input."""
    out = []
    for err in errors:
        item = {"loc": list(err.get("loc", ())), "msg": excerpt(str(err.get("msg", ""))),
                "type": str(err.get("type", "value_error"))}
        if "input" in err:
            item["input"] = excerpt(err["input"])
        out.append(item)
    return out


def storage_failure(exc: BaseException) -> str | None:
    """Why a write failed for want of a usable disk (the 507's detail), or None for other errors."""
    if isinstance(exc, sqlite3.OperationalError):
        text = str(exc)
        if any(k in text for k in ("disk is full", "disk I/O error", "readonly database", "unable to open")):
            return f"the database cannot be written: {text}"
        return None
    if isinstance(exc, OSError) and exc.errno in STORAGE_ERRNOS:
        return f"the data directory cannot be written: {STORAGE_ERRNOS[exc.errno]} ({exc.strerror or exc})"
    return None
