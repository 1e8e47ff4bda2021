"""A simulated pack that rests on its chemistry's open-circuit curve (issue 29).

The paper's circuit (eqs. 1-6) stores charge in a capacitor, so its rested voltage is linear in
charge: a pack scaled from the paper's 5S LiPo rests at 3.89-4.20 V per cell from empty to full,
and at 70 % shows 4.11 V, which every LiPo chart reads as 90 %. A real LiPo at 70 % rests near
3.95 V. ``chemistry_curve_pack`` keeps such a pack's circuit (series resistance, concentration
pair, capacity, heat capacity and transfer) and gives it the rested curve of the chemistry its
description names (``models.chemistry``), on the kernel's extended variant, whose open-circuit
voltage is a curve (``kernel.EXT_OCV_SOC`` knots).

What the mapping keeps and drops (docs/notes/2026-11-27-ocv-shape.md):

* R_0 = R_s (its 0.8 s pair is instantaneous at telemetry rates); R_1 = R_cp at half charge with
  tau_1 = R_cp C_cp; no slow pair, no charge-transfer or diffusion term, no temperature or SoC
  dependence of the resistances (the paper's circuit has none but R_cp's rise near empty);
* the parasitic branch R_p (self-discharge of parts per million per second) is dropped.
"""
from __future__ import annotations

import numpy as np

from gcs_pdm.models import kernel
from gcs_pdm.models.chemistry import chemistry


def chemistry_curve_pack(paper_vector: np.ndarray, chemistry_name: str, cells: int) -> np.ndarray:
    """An extended-variant vector (``kernel.EXT_PACK_PARAMS``) flying ``paper_vector``'s circuit
    (``kernel.PACK_PARAMS``, a whole pack of ``cells`` in series) on ``chemistry_name``'s rested curve."""
    p = np.asarray(paper_vector, dtype=np.float64)
    chem = chemistry(chemistry_name)
    ocv = cells * np.array([chem.ocv(float(s)) for s in kernel.EXT_OCV_SOC])
    steps = np.diff(ocv)
    if np.any(steps <= 0.0):
        # the extended curve is parametrised by positive increments (a monotone curve)
        raise ValueError(f"chemistry {chemistry_name!r}: its rested curve is not increasing on the kernel's knots")
    r_1 = float(kernel.concentration_resistance(p[None], 0.5)[0])
    tau_1 = r_1 * p[kernel.I_CCP]
    values = dict(R_0=p[kernel.I_RS], R_1=r_1, tau_1=tau_1, R_2=0.0, tau_2=10.0 * tau_1, E_r=0.0, E_ct=0.0,
                  k_soc=0.0, soc_knee=0.1, b_ct=0.0, i_ct=1.0, k_d=0.0, tau_d=600.0, C_max=p[kernel.I_CMAX],
                  C_t=p[kernel.I_CT], h=p[kernel.I_H], dU_dT=0.0, ocv_0=ocv[0])
    values.update({f"docv_{k}": float(steps[k - 1]) for k in range(1, kernel.N_OCV_KNOTS)})
    return np.array([values[name] for name in kernel.EXT_PACK_PARAMS], dtype=np.float64)


def rest_voltage(ext_matrix: np.ndarray, states: np.ndarray, ambient_c: float) -> np.ndarray:
    """Terminal voltage (P,) of extended packs in ``states`` (P, 5) at no current."""
    run = kernel.simulate_packs(ext_matrix, states, np.zeros((len(states), 1)), np.zeros((len(states), 1)),
                                ambient_c, variant="extended")
    return run.voltage[:, -1]
