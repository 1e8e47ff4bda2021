#!/usr/bin/env python3
"""Every compiled version in numba's on-disk caches under a tree, one line each: the index file and
the argument types. Two lines for one function that differ only in ``readonly`` or the layout
('C'/'A') are one function compiled twice (docs/notes/2026-11-27-test-time-3.md).

    python scripts/numba_signatures.py [ROOT]      (ROOT: the repository, by default)
"""
from __future__ import annotations

import pickle
import sys
from pathlib import Path


def signatures(root: Path):
    for index in sorted(root.rglob("*.nbi")):
        try:
            with index.open("rb") as f:
                pickle.load(f)  # numba's version
                _stamp, overloads = pickle.loads(f.read())
        except Exception as e:  # noqa: BLE001 - another numba's layout: say so, go on
            yield index, f"unreadable: {e}"
            continue
        for key in overloads:
            yield index, str(key[0])


if __name__ == "__main__":
    root = Path(sys.argv[1] if len(sys.argv) > 1 else Path(__file__).resolve().parents[1])
    for index, sig in signatures(root):
        print(f"{index.relative_to(root).as_posix()}\t{sig}")
