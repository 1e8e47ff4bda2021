"""Where the shared corpus of real autopilot tlogs lives (``../shared/tlogs`` beside the repository,
or ``$GCS_PDM_TLOG_DIR``); tests that need it skip when a user's machine does not have it."""
from __future__ import annotations

import os
from pathlib import Path

import pytest

TLOG_DIR = Path(os.environ.get("GCS_PDM_TLOG_DIR", Path(__file__).parents[2] / ".." / "shared" / "tlogs"))

needs_corpus = pytest.mark.skipif(not TLOG_DIR.is_dir(),
                                  reason=f"shared tlog corpus not found at {TLOG_DIR} (set GCS_PDM_TLOG_DIR)")
