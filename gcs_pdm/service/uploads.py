"""Uploaded flight files: received in chunks straight to disk, bounded by size and by rows, and
checked before they are kept (a tlog must be mostly MAVLink; a table must be a readable flight).

Nothing here holds a whole upload in memory: the body goes to a temporary file under the data
directory (``uploads/.incoming``) with a running size check, a tlog is scanned through ``mmap`` in
windows, and a Parquet file's row count comes from its footer before any column is read.

A table is bounded by what it takes decoded, not by its size on disk (a 671 kB Parquet file of
4.9 M rows x 30 columns took 2.7 GB): before it is loaded, its cells (rows x columns) and an
estimate of its decoded bytes are checked — a Parquet file's from its footer (rows, columns,
uncompressed sizes) and, for text columns, from their dictionaries' value lengths (a dictionary-
encoded text column repeats one long value cheaply on disk, not in memory); a CSV's from its size and
its rows, counted at any line ending (``\n``, ``\r\n`` and a lone ``\r``, which pandas reads as one).
"""
from __future__ import annotations

import mmap
import os
import re
import tempfile
from dataclasses import dataclass
from pathlib import Path

#: what a file name must end with, and the kind it is stored as
UPLOAD_KINDS = {".csv": "csv", ".parquet": "parquet", ".pq": "parquet", ".tlog": "tlog"}
#: longest accepted client file name (characters); the stored name is a short safe form of it
MAX_FILENAME_CHARS = 200
#: the body is copied to disk in pieces of this size (the most one upload holds in memory)
CHUNK_BYTES = 1 << 20
#: room for the multipart framing (boundaries, part headers) around an upload's bytes
MULTIPART_OVERHEAD_BYTES = 64 * 1024
#: one tlog scanning window; a record (8-byte stamp + MAVLink 2 packet + signature) is at most 288 bytes
SCAN_WINDOW_BYTES = 8 << 20
_MAX_RECORD_BYTES = 8 + 12 + 255 + 13


class UploadRefused(Exception):
    """An upload that is not kept: ``status`` is the HTTP code (413 too large, 422 unusable)."""

    def __init__(self, status: int, message: str):
        super().__init__(message)
        self.status = status
        self.message = message


#: decoded bytes a numeric cell takes (pandas' float64/int64), and a text cell beyond its characters
NUMERIC_CELL_BYTES = 8
TEXT_CELL_OVERHEAD_BYTES = 58
#: Parquet physical types decoded as numbers
_NUMERIC_PHYSICAL = frozenset({"BOOLEAN", "INT32", "INT64", "INT96", "FLOAT", "DOUBLE"})


@dataclass(frozen=True)
class UploadLimits:
    max_bytes: int
    max_rows: int
    min_mavlink_fraction: float
    max_cells: int = 10_000_000
    max_decoded_bytes: int = 128 << 20


@dataclass
class ReceivedFile:
    """An upload on disk, not yet checked: its temporary path, size and line count (CSV rows)."""

    path: Path
    size_bytes: int
    newlines: int  # line endings: \n, \r\n or a lone \r
    columns: int = 0  # fields of the first line (a CSV's header), 0 if unknown

    def discard(self) -> None:
        self.path.unlink(missing_ok=True)


class UploadBodyLimit:
    """ASGI middleware: a ``POST`` to ``path`` whose body passes the upload limit (plus multipart
    framing) is refused with 413 as soon as that is known: at once from ``Content-Length``, or while
    the body arrives, before the multipart parser spools the rest. Without it the limit would only be
    checked after the whole body had been received."""

    def __init__(self, app, path: str, max_bytes):
        self.app = app
        self.path = path
        self.max_bytes = max_bytes  # a callable: the service's configured limit

    async def __call__(self, scope, receive, send):
        if scope["type"] != "http" or scope["method"] != "POST" or scope["path"] != self.path:
            await self.app(scope, receive, send)
            return
        from starlette.exceptions import HTTPException
        from starlette.responses import JSONResponse

        limit = self.max_bytes() + MULTIPART_OVERHEAD_BYTES
        detail = f"file: larger than the upload limit of {self.max_bytes()} bytes"
        length = dict(scope["headers"]).get(b"content-length", b"")
        if length.isdigit() and int(length) > limit:
            await JSONResponse({"detail": detail}, status_code=413)(scope, receive, send)
            return
        received = 0

        async def counting_receive():
            nonlocal received
            message = await receive()
            if message["type"] == "http.request":
                received += len(message.get("body", b""))
                if received > limit:
                    # FastAPI passes an HTTPException raised while reading the body on as it is
                    raise HTTPException(413, detail=detail)
            return message

        await self.app(scope, counting_receive, send)


def upload_kind(filename: str) -> tuple[str, str]:
    """The client's base name and the kind its suffix names; UploadRefused(422) otherwise."""
    name = Path(filename or "").name
    if len(name) > MAX_FILENAME_CHARS:
        raise UploadRefused(422, f"file name longer than {MAX_FILENAME_CHARS} characters ({len(name)})")
    kind = UPLOAD_KINDS.get(Path(name).suffix.lower())
    if not name or kind is None:
        raise UploadRefused(422, f"expected a .csv, .parquet or .tlog file, got {name!r}")
    if not any(c.isalnum() for c in name[:-len(Path(name).suffix)]):  # ..csv, _.parquet, " .tlog" (any script's letters count)
        raise UploadRefused(422, f"file name {name!r} has no letter or digit before its suffix")
    return name, kind


def stored_name(filename: str) -> str:
    """A file-system-safe form of the client's name (ASCII letters, digits, ``._-``; at most 80)."""
    stem, suffix = os.path.splitext(filename)
    safe = re.sub(r"[^A-Za-z0-9._-]", "_", stem).strip("._")[:80] or "upload"
    return safe + suffix.lower()


async def receive(upload, folder: Path, max_bytes: int) -> ReceivedFile:
    """Copy a Starlette ``UploadFile`` to a temporary file in ``folder``, CHUNK_BYTES at a time;
    UploadRefused(413) as soon as it passes ``max_bytes`` (422 when empty)."""
    folder.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=folder, suffix=".part")
    path = Path(tmp)
    size = 0
    lines = LineCounter()
    try:
        with os.fdopen(fd, "wb") as out:
            while chunk := await upload.read(CHUNK_BYTES):
                size += len(chunk)
                if size > max_bytes:
                    raise UploadRefused(413, f"larger than the upload limit of {max_bytes} bytes")
                lines.feed(chunk)
                out.write(chunk)
        if size == 0:
            raise UploadRefused(422, "empty file")
    except BaseException:
        path.unlink(missing_ok=True)
        raise
    return ReceivedFile(path, size, lines.endings, lines.header_fields())


#: the most of a file's start kept to count its header's fields
_HEADER_BYTES = 64 * 1024


class LineCounter:
    """Line endings in a stream fed in chunks: ``\n``, ``\r\n`` (one) and a lone ``\r`` (pandas,
    like Python's universal newlines, ends a CSV line at any of them), and the first line's fields."""

    def __init__(self):
        self.endings = 0
        self._cr_at_end = False
        self._head = b""

    def feed(self, chunk: bytes) -> None:
        if not chunk:
            return
        if len(self._head) < _HEADER_BYTES:
            self._head += chunk[:_HEADER_BYTES - len(self._head)]
        crlf = chunk.count(b"\r\n") + (1 if self._cr_at_end and chunk[:1] == b"\n" else 0)
        self.endings += chunk.count(b"\n") + chunk.count(b"\r") - crlf
        self._cr_at_end = chunk[-1:] == b"\r"

    def header_fields(self) -> int:
        first = re.split(rb"\r\n|\r|\n", self._head, maxsplit=1)[0]
        return first.count(b",") + 1 if first.strip() else 0


def mavlink_fraction(path: Path, minimum: float = 0.0, window: int = SCAN_WINDOW_BYTES) -> float:
    """Share of the file's bytes in tlog records with a valid MAVLink CRC (gcs_pdm.mavlink.tlog's
    scanner), read through ``mmap`` one window at a time. Stops early, returning the share seen so
    far, once more than ``1 - minimum`` of the whole file is known not to be MAVLink."""
    from gcs_pdm.mavlink.tlog import scan_tlog_bytes

    size = path.stat().st_size
    if size == 0:
        return 0.0
    allowed_bad = (1.0 - minimum) * size
    valid = 0
    pos = 0
    with open(path, "rb") as fh, mmap.mmap(fh.fileno(), 0, access=mmap.ACCESS_READ) as data:
        while pos < size:
            # A window reaches one record past its end, so a record starting inside it is whole.
            block = data[pos:pos + window + _MAX_RECORD_BYTES]
            last_end = 0
            for *_, packet_start, packet_end in scan_tlog_bytes(block):
                if packet_start - 8 >= window:
                    break
                valid += packet_end - packet_start + 8
                last_end = packet_end
            pos += max(window, last_end)
            if min(pos, size) - valid > allowed_bad:
                return valid / size
    return valid / size


def check_tlog(received: ReceivedFile, minimum: float) -> None:
    share = mavlink_fraction(received.path, minimum)
    if share < minimum:
        raise UploadRefused(422, f"not a MAVLink tlog: only {share:.1%} of its bytes are valid MAVLink records "
                                 f"(at least {minimum:.0%} needed)")


def _parquet(received: ReceivedFile):
    import pyarrow.parquet as pq

    try:
        return pq.ParquetFile(received.path)
    except Exception as exc:  # noqa: BLE001 - pyarrow raises several types for a damaged footer
        raise UploadRefused(422, f"not a readable Parquet file ({type(exc).__name__}: {str(exc)[:200]})") from None


def table_rows(received: ReceivedFile, kind: str) -> int:
    """Rows of a table without loading it: a Parquet file's footer, a CSV file's line count."""
    if kind == "parquet":
        return _parquet(received).metadata.num_rows
    # the header line is no row; a last line without an ending is one
    return max(received.newlines - 1, 0) + (0 if _ends_with_newline(received.path) else 1)


def _ends_with_newline(path: Path) -> bool:
    with open(path, "rb") as fh:
        fh.seek(-1, os.SEEK_END)
        return fh.read(1) in (b"\n", b"\r")


def check_rows(received: ReceivedFile, kind: str, max_rows: int) -> None:
    rows = table_rows(received, kind)
    if rows > max_rows:
        raise UploadRefused(413, f"{rows} rows, more than the upload limit of {max_rows} rows")


def parquet_decoded_bytes(received: ReceivedFile, stop_above: int) -> int:
    """What a Parquet file takes decoded, from its footer: numeric cells at NUMERIC_CELL_BYTES, text
    cells at their values' lengths (read as dictionary indices and values, so a long value repeated
    is counted per row without being expanded) plus TEXT_CELL_OVERHEAD_BYTES. Stops counting once
    past ``stop_above``."""
    import pyarrow as pa
    import pyarrow.compute as pc

    pf = _parquet(received)
    meta = pf.metadata
    schema = pf.schema_arrow
    total = 0
    text_columns = []
    for i in range(meta.num_columns):
        physical = meta.schema.column(i).physical_type
        if physical in _NUMERIC_PHYSICAL:
            total += meta.num_rows * NUMERIC_CELL_BYTES
        else:
            text_columns.append(meta.schema.column(i).path.split(".")[0])
    # everything stored, uncompressed: no column decodes to less than its pages
    stored = sum(meta.row_group(g).total_byte_size for g in range(meta.num_row_groups))
    if max(total, stored) > stop_above:
        return max(total, stored)
    names = [n for n in dict.fromkeys(text_columns) if n in schema.names]
    if not names:
        return total
    import pyarrow.parquet as pq

    # pyarrow expands a dictionary-encoded column unless asked to keep the dictionary
    as_dict = pq.ParquetFile(received.path, read_dictionary=names)
    for name in names:
        for g in range(meta.num_row_groups):
            column = as_dict.read_row_group(g, columns=[name], use_threads=False).column(0)
            for chunk in column.chunks:
                arr = chunk
                if pa.types.is_dictionary(arr.type):
                    lengths = pc.binary_length(arr.dictionary) if _is_binary(arr.dictionary.type) else None
                    per_row = (pc.take(lengths, arr.indices) if lengths is not None else None)
                else:
                    per_row = pc.binary_length(arr) if _is_binary(arr.type) else None
                text = int(pc.sum(per_row).as_py() or 0) if per_row is not None else arr.nbytes
                total += text + len(arr) * TEXT_CELL_OVERHEAD_BYTES
                if total > stop_above:
                    return total
    return total


def _is_binary(t) -> bool:
    import pyarrow as pa

    return pa.types.is_string(t) or pa.types.is_binary(t) or pa.types.is_large_string(t) or pa.types.is_large_binary(t)


def check_size(received: ReceivedFile, kind: str, limits: UploadLimits) -> None:
    """Cells (rows x columns) and decoded bytes within the limits, before the table is loaded."""
    if kind == "parquet":
        meta = _parquet(received).metadata
        rows, columns = meta.num_rows, meta.num_columns
    else:
        rows, columns = table_rows(received, kind), max(received.columns, 1)
    cells = rows * columns
    if cells > limits.max_cells:
        raise UploadRefused(413, f"{rows} rows x {columns} columns = {cells} cells, more than the upload limit of "
                                 f"{limits.max_cells} cells (max_upload_cells)")
    if kind == "parquet":
        decoded = parquet_decoded_bytes(received, limits.max_decoded_bytes)
    else:  # every character may become part of a text cell, every cell at least a number
        decoded = received.size_bytes + cells * NUMERIC_CELL_BYTES
    if decoded > limits.max_decoded_bytes:
        raise UploadRefused(413, f"would take {'more than ' if kind == 'parquet' else 'about '}{decoded} bytes "
                                 f"decoded, more than the upload limit of {limits.max_decoded_bytes} "
                                 "(max_upload_decoded_bytes)")


def check_table(received: ReceivedFile, filename: str, kind: str) -> None:
    """The table must be readable by gcs_pdm.fitting.logs with at least a motor flight's columns."""
    from gcs_pdm.fitting.logs import read_table
    from gcs_pdm.logs.tables import MOTOR, FlightDataError

    # read_table picks the reader by suffix: give it a name with the kind's suffix beside the upload
    named = received.path.with_suffix(".csv" if kind == "csv" else ".parquet")
    os.replace(received.path, named)
    received.path = named
    try:
        read_table(named, MOTOR, name=filename)
    except FlightDataError as exc:
        raise UploadRefused(422, str(exc).replace(str(named), filename)) from None
    except Exception as exc:  # noqa: BLE001 - a damaged table
        raise UploadRefused(422, f"{filename}: cannot read table ({type(exc).__name__}: {exc})") from None


def check(received: ReceivedFile, filename: str, kind: str, limits: UploadLimits) -> None:
    """UploadRefused when the received file cannot be kept; the cheap bounds come first."""
    if kind == "tlog":
        check_tlog(received, limits.min_mavlink_fraction)
        return
    check_rows(received, kind, limits.max_rows)
    check_size(received, kind, limits)
    check_table(received, filename, kind)
