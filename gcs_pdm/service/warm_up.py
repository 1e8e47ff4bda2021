"""The demo's compiled paths as ``gcs_pdm.compiled`` groups: the replay's (the filters, the
held-current trace) and the live loop's Monte Carlo predictions, the planner's simulator and the
simulated vehicle, through the same adapters the service calls."""
from __future__ import annotations

from gcs_pdm.compiled import Group
from gcs_pdm.replay.warm_up import REPLAY_GROUPS


def predictions() -> None:
    """The live loop's Monte Carlo predictions from an estimator (time to cut-off, a route's risk),
    the planner's vehicle simulator on the demo's Table III route (as ``demo.table3_mission`` plans
    it) and the simulated vehicle's truth: the whole-vehicle simulation."""
    import numpy as np

    from gcs_pdm.estimation.prediction import FutureLoad, predict_from_estimator
    from gcs_pdm.models.params import builtin
    from gcs_pdm.vehicle.presets import DEFAULT_PRESET, PRESETS
    from gcs_pdm.planning.plan import make_plan
    from gcs_pdm.planning.simulator import VehicleSimulator, original_order
    from gcs_pdm.planning.table3_scenario import preflight_scenario
    from gcs_pdm.service import adapters
    from gcs_pdm.sim.core import warm_up_kernel
    from gcs_pdm.sim.model import SimConfig
    from gcs_pdm.sim.truth import true_parameters

    est = adapters.make_estimator(PRESETS[DEFAULT_PRESET], builtin("paper_si"))
    adapters.prediction_job(est, 3000.0, 20.0, [])()
    load = FutureLoad.constant(3000.0, 600.0, 10.0, 20.0)
    adapters.route_risk(est, load, [], n_samples=8)
    # the diagnoser's prognosis against the mission's load keeps its trajectories' medians
    predict_from_estimator(est, load, rng=np.random.default_rng(0), n_samples=4, trajectories=True)
    scenario = preflight_scenario(10)
    make_plan(VehicleSimulator.for_scenario(scenario, true_parameters()), original_order(scenario), "original")
    warm_up_kernel(SimConfig(limits=scenario.limits.kernel_limits()))


PREDICTIONS = Group("predictions", predictions, ("gcs_pdm.models.topology", "_simulate"))
#: what ``gcs-pdm demo`` prepares
DEMO_GROUPS = (*REPLAY_GROUPS, PREDICTIONS)
