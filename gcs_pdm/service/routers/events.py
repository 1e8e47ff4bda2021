"""``/events``: live updates, as Server-Sent Events or by polling."""
from __future__ import annotations

import asyncio
import json

from fastapi import APIRouter, Query, Request
from fastapi.responses import StreamingResponse

from gcs_pdm.service import schemas as S
from gcs_pdm.service.routers.deps import SQLITE_INT_MAX, ServiceDep, finite

router = APIRouter(prefix="/events")


@router.get("/poll", responses=S.errors(422))
def events_poll(service: ServiceDep, since: int = Query(0, ge=0, le=SQLITE_INT_MAX)) -> list[dict]:
    return [finite(e.to_dict()) for e in service.events.since(since)]


@router.get("", responses={200: {"content": {"text/event-stream": {}}}, **S.errors(422)})
async def events(request: Request, service: ServiceDep, since: int | None = Query(None, ge=0, le=SQLITE_INT_MAX)):
    """Server-Sent Events: one ``event: <kind>`` per fault, plan, upload, job change, status tick."""
    start = since
    if start is None:
        header = request.headers.get("last-event-id", "").strip()
        # ASCII digits only ("²".isdigit() is true but no int), and no more than a row id can be
        start = int(header) if header.isascii() and header.isdigit() and len(header) < 19 else service.events.last_seq

    async def stream():
        seq = start
        yield ": connected\n\n"
        while not await request.is_disconnected():
            batch = await asyncio.to_thread(service.events.wait, seq, 1.0)
            if not batch:
                yield ": keep-alive\n\n"
                continue
            for ev in batch:
                seq = ev.seq
                yield f"id: {ev.seq}\nevent: {ev.kind}\ndata: {json.dumps(finite(ev.to_dict()))}\n\n"

    return StreamingResponse(stream(), media_type="text/event-stream",
                             headers={"Cache-Control": "no-cache", "X-Accel-Buffering": "no"})
