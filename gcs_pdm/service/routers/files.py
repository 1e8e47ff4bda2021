"""``/files`` (uploaded flight files) and ``/tlogs`` (the recorded and uploaded tlogs).

An upload is streamed to disk and checked by gcs_pdm.service.uploads (size, rows, content) before
it is kept; the limits are the service's configuration (``max_upload_bytes``, ``max_upload_rows``,
``tlog_min_mavlink_fraction``)."""
from __future__ import annotations

import asyncio
from pathlib import Path

from fastapi import APIRouter, File, HTTPException, UploadFile

from gcs_pdm.service import schemas as S
from gcs_pdm.service import uploads
from gcs_pdm.service.routers.deps import AUTH, ServiceDep, unprocessable

router = APIRouter()


@router.post("/files", response_model=S.FileOut, status_code=201, dependencies=AUTH,
             responses=S.errors(401, 413, 422))
async def upload_file(service: ServiceDep, file: UploadFile = File(...)):
    received = None
    try:
        name, kind = uploads.upload_kind(file.filename)
        received = await uploads.receive(file, service.incoming_dir, service.config.max_upload_bytes)
        await asyncio.to_thread(uploads.check, received, name, kind, service.upload_limits)
        file_id = service.save_upload(name, kind, received)
    except BaseException as exc:
        if received is not None:
            received.discard()  # nothing refused or half-received stays on disk
        if not isinstance(exc, uploads.UploadRefused):
            raise
        if exc.status == 422:
            raise unprocessable("file", exc.message) from None
        raise HTTPException(exc.status, detail=f"file: {exc.message}") from None
    return service.store.file(file_id)


@router.get("/files", response_model=list[S.FileOut])
def files(service: ServiceDep):
    return service.store.files()


@router.get("/tlogs", response_model=list[S.TlogOut])
def tlogs(service: ServiceDep):
    # paths relative to the data directory (a tlog elsewhere: its name): the server's layout is not
    # the client's business
    return [{**t, "path": shown_path(t["path"], service.config.data_path)} for t in service.store.tlogs()]


def shown_path(path: str, data_dir: Path) -> str:
    p = Path(path)
    try:
        return p.relative_to(data_dir).as_posix()
    except ValueError:
        return p.name
