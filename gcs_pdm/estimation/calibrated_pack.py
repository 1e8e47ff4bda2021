"""A self-calibrated pack's learned model as the kernel's extended-variant pack (issue 32 item 2, issue 29).

A pack whose state comes from a ``calibration.PackCalibrator`` has a learned model — the
chemistry's rested curve with its offset ΔV and scale k, R₀ at 25 °C with the Arrhenius factor E,
a fast pair R₁/τ₁ and a slow pair R₂/τ₂, the capacity Q_prior / g — and its count-down flies it
(``calibrated_cutoff``). A route's prediction (landing SoC, P(failure)) flies packs through the
kernel, so this module writes that model as the kernel's extended-variant vector
(``kernel.EXT_PACK_PARAMS``), for the filter's mean state or for states drawn from its covariance:

* R_0, R_1, R_2: the learned values at the present temperature's Arrhenius factor, held there
  (E_r = 0), as the count-down holds them. The kernel could carry E (its f(T) is the same factor),
  but it would apply it to its own modelled heating: on a pack without a temperature sensor the
  filter's E is learned against a modelled temperature (6582 ± 1095 K against the prior's 2500 on
  the note's case, whose truth has none), and the resistances then fell 38 % over the flight:
  the count-down 28 % long (docs/notes/2026-11-27-calibrated-pack.md);
  τ_1 = the chemistry's τ₁ · R₁ / R₁_prior and τ_2 = ``TAU2_FACTOR`` τ₁, the calibrator's own;
  C_max = Q_prior / g;
* the rested curve: the calibrator's, sampled at ``kernel.EXT_OCV_SOC``; the kernel draws a
  monotone cubic through those knots where the calibrator interpolates linearly between 21;
* the sag's rise near empty (``calibrated_cutoff.low_charge_rise``, the paper's fitted pack's) is
  exactly the kernel's low-charge factor 1 + k_soc exp(−SoC / soc_knee) up to a constant, which
  the resistances carry; the learned resistances are taken as the present SoC's (divided by its rise);
* what the model does not explain now (``CutoffModel.sag_beyond_model_ohm``: the recent loaded
  voltage's shortfall below the model, per ampere) is added to R_0, as the count-down adds it to
  the sag; a resistance cannot be negative, so R_0 is floored at 0;
* the kernel's pack has a thermal model the calibrator does not (it reads the measured
  temperature): C_t and h are the description's kernel pack's, dU/dT = 0; no charge-transfer or
  diffusion term (b_ct = k_d = 0).

The pack's temperature is the kernel's own (from the pack's estimated one): it sets the limits
and the peak temperature, not the resistances. The measured differences (voltage, time to cut-off) against the
calibrator's own model are in docs/notes/2026-11-27-calibrated-pack.md.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from gcs_pdm.estimation.calibrated_cutoff import CutoffModel, low_charge_rise, low_charge_rise_terms
from gcs_pdm.estimation.calibration import (I_DV, I_E, I_G, I_K, I_R0, I_R1, I_R2, I_SOC, I_V1, I_V2, TAU2_FACTOR,
                                            PackCalibrator)
from gcs_pdm.models import kernel

_GRID = np.linspace(0.0, 1.0, 21)
#: the diffusion term's time constant is irrelevant at k_d = 0, but must be positive (a decay)
_UNUSED_TAU_D_S = 600.0


@dataclass(frozen=True)
class CalibratedCircuit:
    """One calibrated pack: its filter's model now and what the kernel needs beyond it."""

    model: CutoffModel
    #: the chemistry's fast time constant at the prior fast resistance (τ₁ follows R₁)
    tau1_s: float
    r1_prior_ohm: float
    #: the description's kernel pack's thermal mass (J/K) and transfer to the air (W/K)
    heat_capacity_j_k: float
    heat_transfer_w_k: float

    @classmethod
    def of(cls, cal: PackCalibrator, paper_vector: np.ndarray) -> "CalibratedCircuit | None":
        """The calibrator's model now with the thermal values of ``paper_vector``
        (``kernel.PACK_PARAMS``); None before its first voltage."""
        model = CutoffModel.of(cal)
        if model is None:
            return None
        return cls(model, float(cal.chem.tau1_s), float(cal.r1p), float(paper_vector[kernel.I_CT]),
                   float(paper_vector[kernel.I_H]))

    def vectors(self, states: np.ndarray) -> np.ndarray:
        """(N, N_EXT_PARAMS) extended vectors of the rows of ``states`` (calibrator states, N_STATE wide)."""
        s = np.atleast_2d(states)
        m = self.model
        rise_c, k_soc, knee = low_charge_rise_terms()
        # the learned resistances are the present SoC's; the kernel multiplies them by its rise
        per_rise = rise_c / low_charge_rise(np.clip(s[:, I_SOC], 0.0, 1.0))
        # the resistances at the present temperature's factor, held (E_r = 0), as the count-down holds them
        f_now = np.exp(s[:, I_E] * m.temp_u)
        cell = np.interp(kernel.EXT_OCV_SOC, _GRID, m.table)
        ocv = m.cells * (cell[None] + s[:, I_DV, None] + s[:, I_K, None] * (cell[None] - m.mid))
        steps = np.diff(ocv, axis=1)
        if np.any(steps <= 0.0):
            # the kernel's curve is parametrised by positive increments (a monotone curve)
            raise ValueError("calibrated pack: its rested curve is not increasing on the kernel's knots")
        out = np.zeros((s.shape[0], kernel.N_EXT_PARAMS))
        out[:, kernel.E_R0] = np.maximum(s[:, I_R0] * f_now + m.sag_beyond_model_ohm(s), 0.0) * per_rise
        out[:, kernel.E_R1] = s[:, I_R1] * f_now * per_rise
        out[:, kernel.E_TAU1] = self.tau1_s * s[:, I_R1] / self.r1_prior_ohm
        out[:, kernel.E_R2] = s[:, I_R2] * f_now * per_rise
        out[:, kernel.E_TAU2] = TAU2_FACTOR * self.tau1_s
        out[:, kernel.E_ER] = 0.0
        out[:, kernel.E_KSOC] = k_soc
        out[:, kernel.E_KNEE] = knee
        out[:, kernel.E_ICT] = 1.0  # b_ct = 0: no charge-transfer term
        out[:, kernel.E_TAUD] = _UNUSED_TAU_D_S
        out[:, kernel.E_CMAX] = m.q0 / s[:, I_G]
        out[:, kernel.E_CT] = self.heat_capacity_j_k
        out[:, kernel.E_H] = self.heat_transfer_w_k
        out[:, kernel.E_OCV0] = ocv[:, 0]
        out[:, kernel.E_OCV0 + 1:] = steps
        return out

    def mean_vector(self) -> np.ndarray:
        """The extended vector of the filter's mean state."""
        return self.vectors(self.model.x[None])[0]

    @staticmethod
    def pack_states(states: np.ndarray, temperature_c: np.ndarray | float) -> np.ndarray:
        """(N, 5) kernel states (``kernel.EXT_PACK_STATE``) of calibrator states: SoC and the pairs'
        voltages as the filter has them, no surface depletion, the pack at ``temperature_c``."""
        s = np.atleast_2d(states)
        x = np.zeros((s.shape[0], kernel.N_EXT_STATE))
        x[:, kernel.X_SOC] = s[:, I_SOC]
        x[:, kernel.X_V1] = s[:, I_V1]
        x[:, kernel.X_V2] = s[:, I_V2]
        x[:, kernel.X_T] = temperature_c
        return x


@dataclass(frozen=True)
class CalibratedPacks:
    """A prediction's extended packs (``extended_prediction.ExtendedPacks``' interface): the
    estimator's self-calibrated packs, drawn from their filters' covariance."""

    is_ext: np.ndarray
    circuits: tuple[CalibratedCircuit | None, ...]

    @classmethod
    def of(cls, estimator) -> "CalibratedPacks | None":
        """The estimator's self-calibrated packs (None if it has none initialised)."""
        calib = getattr(estimator, "calib", None) or []
        params = estimator.packs.params
        circuits = tuple(None if c is None else CalibratedCircuit.of(c, params[b]) for b, c in enumerate(calib))
        if not any(c is not None for c in circuits):
            return None
        return cls(np.array([c is not None for c in circuits]), circuits)

    def sample(self, x0_paper: np.ndarray, n: int, rng: np.random.Generator, rel_sigma: float
               ) -> tuple[np.ndarray, np.ndarray]:
        """(n, P, 5) states — the other packs' ``x0_paper`` (n, P, 4) in the first four columns,
        a calibrated pack's drawn from its filter — and (n, P, N_EXT_PARAMS) extended values (zero
        rows for the others). The thermal values, which no filter learns, spread log-normally by
        ``rel_sigma``, as the prediction spreads every kernel pack's."""
        x0 = np.zeros((n, self.is_ext.size, kernel.N_EXT_STATE))
        x0[..., :kernel.N_PACK_STATE] = x0_paper
        params = np.zeros((n, self.is_ext.size, kernel.N_EXT_PARAMS))
        for b, circuit in enumerate(self.circuits):
            if circuit is None:
                continue
            states = circuit.model.draw_states(rng, n)
            params[:, b] = circuit.vectors(states)
            params[:, b, [kernel.E_CT, kernel.E_H]] *= np.exp(rng.normal(0.0, rel_sigma, size=(n, 2)))
            x0[:, b] = circuit.pack_states(states, x0_paper[:, b, kernel.S_T])
        return x0, params
