"""A pack's parameters carried over to another pack of the same chemistry (docs/vehicles.md).

Cells in series add voltage and resistance; capacity (more parallel cells, bigger cells) divides
resistance and multiplies capacitance and charge. So for a pack of S cells and capacity Q made
from a reference pack of S0 cells and Q0:

* resistances (R_s, R_p, R_cp0, R_cp1) × (S/S0)·(Q0/Q); R_cp2 (an exponent in SoC) unchanged;
* capacitances (C_s, C_b, C_cp) × (S0/S)·(Q/Q0), so every R–C time constant is unchanged;
* q_max = C_b · V_full (full at the chemistry's full-cell voltage), C_max = min(Q, q_max);
* thermal inertia C_t × m/m0 with the pack's mass m ∝ S·Q; heat transfer h × (m/m0)^(2/3)
  (surface area).
"""
from __future__ import annotations

import numpy as np

from gcs_pdm.models import kernel


def scale_pack_vector(reference: np.ndarray, ref_cells: int, ref_capacity_c: float, cells: int, capacity_c: float,
                      full_cell_voltage: float) -> np.ndarray:
    """``reference`` (PACK_PARAMS order) scaled to ``cells`` in series and ``capacity_c`` coulombs."""
    v = np.array(reference, dtype=np.float64, copy=True)
    r = (cells / ref_cells) * (ref_capacity_c / capacity_c)
    for i in (kernel.I_RS, kernel.I_RP, kernel.I_RCP0, kernel.I_RCP1):
        v[i] *= r
    for i in (kernel.I_CS, kernel.I_CB, kernel.I_CCP):
        v[i] /= r
    v[kernel.I_QMAX] = v[kernel.I_CB] * full_cell_voltage * cells
    v[kernel.I_CMAX] = min(capacity_c, v[kernel.I_QMAX])
    mass_ratio = (cells / ref_cells) * (capacity_c / ref_capacity_c)
    v[kernel.I_CT] *= mass_ratio
    v[kernel.I_H] *= mass_ratio ** (2.0 / 3.0)
    return v
