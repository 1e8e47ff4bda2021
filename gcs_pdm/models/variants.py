"""The pack model variants a parameter set may name (docs/model.md, "Model variants").

Their own module, not the kernel's, so that reading or validating a parameter set does not import
numba (every command's start-up), and the kernel and the parameter sets share one definition.
"""
from __future__ import annotations

MODEL_VARIANTS: tuple[str, ...] = ("paper", "extended")
