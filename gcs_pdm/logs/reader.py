"""Open an autopilot's own log by its extension: DataFlash ``.bin`` or PX4 ULog ``.ulg``.

Kept apart from :mod:`gcs_pdm.logs.series` (the format-neutral tables) so the format readers can
build those tables without importing back into the module that dispatches to them.
"""
from __future__ import annotations

from pathlib import Path

from gcs_pdm.logs.tables import FlightDataError
from gcs_pdm.logs.dataflash import series_from_dataflash
from gcs_pdm.logs.series import LogSeries
from gcs_pdm.logs.ulog import series_from_ulog


LOG_SUFFIXES = (".bin", ".ulg")


def read_log(path: str | Path) -> LogSeries:
    """A DataFlash (``.bin``) or ULog (``.ulg``) file as :class:`LogSeries`, by extension."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix == ".bin":
        return series_from_dataflash(path)
    if suffix == ".ulg":
        return series_from_ulog(path)
    raise FlightDataError(f"{path}: not an autopilot log (expected {' or '.join(LOG_SUFFIXES)})")
