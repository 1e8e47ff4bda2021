"""A described vehicle's simulated pack on its chemistry's rested curve (``sim.pack_curves``, issue 29)."""
from __future__ import annotations

import numpy as np
import pytest

from gcs_pdm.models import kernel
from gcs_pdm.models.chemistry import chemistry
from gcs_pdm.sim.model import SimConfig, VehicleModel, vehicle_config
from gcs_pdm.sim.pack_curves import chemistry_curve_pack, rest_voltage
from gcs_pdm.sim.routes import mission_from_enu
from gcs_pdm.vehicle.model_inputs import model_inputs
from gcs_pdm.vehicle.presets import PRESETS


@pytest.mark.parametrize("name", ["lipo", "liion", "lifepo4", "lihv"])
def test_the_pack_rests_on_its_chemistrys_curve(name):
    spec = PRESETS["quad-6s"].packs[0]
    ext = chemistry_curve_pack(model_inputs(PRESETS["quad-6s"]).pack_matrix[0], name, spec.cells_series)[None]
    # the extended curve is a monotone cubic through the table's values at its knots, and between
    # them within 10 mV of the table (whose own points are every 0.05)
    for soc, tol in ((0.03, 1e-9), (0.3, 1e-9), (0.5, 1e-9), (0.7, 1e-9), (0.95, 1e-9), (0.475, 0.01), (0.8125, 0.01)):
        v = rest_voltage(ext, kernel.initial_extended_state(ext, soc, 25.0), 25.0)[0]
        assert v / spec.cells_series == pytest.approx(chemistry(name).ocv(soc), abs=tol)


def test_a_lipo_quad_at_70_percent_rests_as_a_lipo_and_its_soc_is_its_charge():
    desc = PRESETS["quad-4s"]
    legs = [(200, 0, 30), (200, 200, 30)]
    model = VehicleModel(vehicle_config(desc, mission=tuple(mission_from_enu(legs, takeoff_alt_m=30)),
                                        initial_soc=0.7, chemistry_curves=True, start_delay_s=1.0))
    rest = model.state()
    assert rest.pack_voltage_v[0] == pytest.approx(4 * chemistry("lipo").ocv(0.7), abs=0.01)  # 15.80 V, not 16.43
    loaded = []
    for _ in range(600):  # 60 s
        model.step(0.1)
        s = model.state()
        if s.pack_current_a[0] > 5.0:
            loaded.append((s.pack_current_a[0], s.pack_voltage_v[0], s.pack_soc[0]))
    s = model.state()
    assert not s.failed and loaded
    # the truth's SoC is its charge: what the current drew over the pack's capacity
    capacity_c = model._ext_matrix[0, kernel.E_CMAX]
    assert s.pack_soc[0] == pytest.approx(0.7 - s.pack_charge_c[0] / capacity_c, abs=1e-6)
    # under load the terminal voltage sags below the curve at that charge
    i, v, soc = loaded[-1]
    assert v < 4 * chemistry("lipo").ocv(soc) - 0.5 * i * model._ext_matrix[0, kernel.E_R0]


def test_the_paper_aircraft_names_no_chemistry_curve():
    with pytest.raises(ValueError, match="chemistry_curves"):
        VehicleModel(SimConfig(chemistry_curves=True))


def test_sim_command_flies_chemistry_curves_on_a_described_vehicle_only():
    from gcs_pdm.cli import build_parser
    from gcs_pdm.sim.cli import build_config

    args = build_parser("sim").parse_args(["sim", "--vehicle", "quad-4s", "--chemistry-curves", "--soc", "0.7"])
    config, _ = build_config(args)
    assert config.chemistry_curves and config.vehicle.name == "quad-4s"
    with pytest.raises(SystemExit, match="needs --vehicle"):
        build_config(build_parser("sim").parse_args(["sim", "--chemistry-curves"]))
