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
    for i, name in enumerate(kernel.PACK_PARAMS):
        v[i] *= value_scale(name, ref_cells, ref_capacity_c, cells, capacity_c)
    v[kernel.I_QMAX] = v[kernel.I_CB] * full_cell_voltage * cells
    v[kernel.I_CMAX] = min(capacity_c, v[kernel.I_QMAX])
    return v


#: how each named pack value (paper PACK_PARAMS and extended EXT_PACK_PARAMS names) scales from a
#: reference pack to another: exponents (a, b, c) of the factor (S/S0)^a · (Q/Q0)^b · (m/m0)^c, with
#: the pack's mass m ∝ S·Q. Resistances go as S/Q, capacitances as Q/S, charges and currents as Q,
#: voltages as S; time constants, exponents in SoC and activation temperatures do not change.
SCALING_EXPONENTS: dict[str, tuple[float, float, float]] = {
    **{k: (1.0, -1.0, 0.0) for k in ("R_s", "R_p", "R_cp0", "R_cp1", "R_0", "R_1", "R_2")},
    **{k: (-1.0, 1.0, 0.0) for k in ("C_s", "C_b", "C_cp")},
    **{k: (0.0, 1.0, 0.0) for k in ("q_max", "C_max", "i_ct")},
    **{k: (1.0, 0.0, 0.0) for k in ("ocv_0", "b_ct", "dU_dT")},
    "C_t": (0.0, 0.0, 1.0),
    "h": (0.0, 0.0, 2.0 / 3.0),
}


def value_scale(name: str, ref_cells: int, ref_capacity_c: float, cells: int, capacity_c: float) -> float:
    """Factor carrying the value ``name`` from a reference pack (S0 cells, Q0 C) to a pack of ``cells``
    and ``capacity_c``; 1 for values that do not scale (tau_*, R_cp2, E_r, k_soc, k_d). The open-circuit
    voltage increments ``docv_k`` scale with the cells, as ``ocv_0``."""
    a, b, c = SCALING_EXPONENTS.get("ocv_0" if name.startswith("docv_") else name, (0.0, 0.0, 0.0))
    s, q = cells / ref_cells, capacity_c / ref_capacity_c
    return s ** a * q ** b * (s * q) ** c


def scale_values(values: dict[str, float], ref_cells: int, ref_capacity_c: float, cells: int,
                 capacity_c: float) -> dict[str, float]:
    """Named values (e.g. the extended variant's) carried to another pack by ``value_scale``."""
    return {k: float(v) * value_scale(k, ref_cells, ref_capacity_c, cells, capacity_c) for k, v in values.items()}
