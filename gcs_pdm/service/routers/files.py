"""``/files`` (uploaded flight files) and ``/tlogs`` (the recorded and uploaded tlogs)."""
from __future__ import annotations

import asyncio
from pathlib import Path

from fastapi import APIRouter, File, HTTPException, UploadFile

from gcs_pdm.service import schemas as S
from gcs_pdm.service.routers.deps import AUTH, ServiceDep, unprocessable

router = APIRouter()

UPLOAD_KINDS = {".csv": "csv", ".parquet": "parquet", ".pq": "parquet", ".tlog": "tlog"}
MAX_UPLOAD_BYTES = 512 * 1024 * 1024


@router.post("/files", response_model=S.FileOut, status_code=201, dependencies=AUTH)
async def upload_file(service: ServiceDep, file: UploadFile = File(...)):
    name = Path(file.filename or "").name
    kind = UPLOAD_KINDS.get(Path(name).suffix.lower())
    if not name or kind is None:
        raise unprocessable("file", f"expected a .csv, .parquet or .tlog file, got {name!r}")
    data = await file.read(MAX_UPLOAD_BYTES + 1)
    if len(data) > MAX_UPLOAD_BYTES:
        raise HTTPException(413, detail=f"file: larger than {MAX_UPLOAD_BYTES} bytes")
    if not data:
        raise unprocessable("file", "empty file")
    problem = await asyncio.to_thread(service.check_upload, name, kind, data)
    if problem:
        raise unprocessable("file", problem)
    file_id = service.save_upload(name, kind, data)
    return service.store.file(file_id)


@router.get("/files", response_model=list[S.FileOut])
def files(service: ServiceDep):
    return service.store.files()


@router.get("/tlogs", response_model=list[S.TlogOut])
def tlogs(service: ServiceDep):
    return service.store.tlogs()
