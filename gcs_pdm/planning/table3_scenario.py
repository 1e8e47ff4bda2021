"""The Table III scenario, rebuilt: ten numbered waypoints, a motor fault between 2 and 3.

The paper does not publish its geometry, so this builds one of the same kind, deterministically:
ten waypoints with rewards around home, flown in numbered order; the vehicle (the simulated
vehicle's *true* parameters) takes off with full packs, flies waypoints 1 and 2 healthy, and half
way to waypoint 3 its aft motor loses part of its power. The planning scenario starts there, with
what the estimator would report (per-pack SoC, currents and temperatures, motor temperatures),
over the waypoints not yet visited (3..n for the n-waypoint sub-scenario). The limits are chosen so
that the original order cannot be completed on the degraded vehicle while good subsets can
(``check_table3`` verifies it; the tests keep it true).
"""
from __future__ import annotations

import numpy as np

from gcs_pdm.models import kernel
from gcs_pdm.models.params import ParameterSet
from gcs_pdm.models.powertrain import MotorFault, PowertrainState
from gcs_pdm.planning.scenario import Home, PlanLimits, Scenario, StartState, Waypoint
from gcs_pdm.planning.simulator import VehicleSimulator

#: (number, east m, north m, altitude m above home, reward) in a 10 km square about home, drawn once
#: (numpy default_rng(0)) and kept: the numbered order criss-crosses the field, as unplanned missions do
TABLE3_WAYPOINTS: tuple[tuple[int, float, float, float, float], ...] = (
    (1, 1370.0, -2300.0, 120.0, 72.0),
    (2, -4590.0, -4830.0, 100.0, 43.0),
    (3, 3130.0, 4130.0, 100.0, 49.0),
    (4, 1070.0, 2290.0, 100.0, 89.0),
    (5, 440.0, 4350.0, 100.0, 75.0),
    (6, 3160.0, -4970.0, 150.0, 88.0),
    (7, 3570.0, -4660.0, 150.0, 43.0),
    (8, 2300.0, -3240.0, 150.0, 66.0),
    (9, 3630.0, 410.0, 120.0, 86.0),
    (10, -2000.0, -770.0, 150.0, 63.0),
)
TABLE3_FAULT = MotorFault("aft", 0.7)
TABLE3_LIMITS = PlanLimits(pack_cutoff_v=17.5, pack_max_temp_c=60.0, motor_max_temp_c=80.0, landing_reserve_soc=0.15)
TABLE3_HOME = Home(lat_deg=37.0870, lon_deg=-76.3800, ground_alt_m=0.0, ground_temp_c=22.0)
TABLE3_SIZES = (7, 8, 9, 10)


def _pre_fault_state(truth: ParameterSet) -> tuple[PowertrainState, tuple[float, float, float], float]:
    """Fly the truth from a full, cool vehicle on the ground over waypoints 1, 2 and half way to 3."""
    w = {n: (e, no, a) for n, e, no, a, _ in TABLE3_WAYPOINTS}
    mid = tuple(0.5 * (np.array(w[2]) + np.array(w[3])))
    legs = (Waypoint(1, *w[1], reward=0.0), Waypoint(2, *w[2], reward=0.0), Waypoint(99, *mid, reward=0.0))
    t0 = TABLE3_HOME.ground_temp_c
    ground = StartState(east_m=0.0, north_m=0.0, alt_m=0.0, pack_temp_c=(t0,) * 4, motor_temp_c=(t0,) * 2,
                        pack_soc=(1.0,) * 4)
    sc = Scenario(name="pre-fault", home=TABLE3_HOME, start=ground, waypoints=legs, limits=TABLE3_LIMITS)
    sim = VehicleSimulator.for_scenario(sc, truth, dt_s=1.0)
    st = sim.start_state()
    for i in range(3):
        st, ok = sim.advance(st, np.array([i]))
        if not ok[0]:
            raise RuntimeError("the healthy vehicle failed before the fault; the scenario is broken")
    state = PowertrainState(pack_state=st.x[0], motor_temp_c=st.motor_temp[0])
    return state, mid, float(st.time_s[0])


def table3_scenario(truth: ParameterSet, n_waypoints: int = 10, params: str | ParameterSet = "paper_si") -> Scenario:
    """The n-waypoint sub-scenario (waypoints 1..n) starting at the fault, planning over 3..n."""
    if n_waypoints not in range(3, len(TABLE3_WAYPOINTS) + 1):
        raise ValueError(f"n_waypoints: expected 3..{len(TABLE3_WAYPOINTS)}, got {n_waypoints}")
    state, pos, t = _pre_fault_state(truth)
    pm = truth.pack_matrix()
    soc = kernel.state_of_charge(pm, state.pack_state)
    # what the estimator reports: SoC, temperatures and the cruise current through each pack
    cruise_current = state.pack_state[:, kernel.S_QS] / (pm[:, kernel.I_RS] * pm[:, kernel.I_CS])
    start = StartState(east_m=pos[0], north_m=pos[1], alt_m=pos[2], time_s=t,
                       pack_soc=tuple(round(float(s), 5) for s in soc),
                       pack_temp_c=tuple(round(float(v), 3) for v in state.pack_state[:, kernel.S_T]),
                       motor_temp_c=tuple(round(float(v), 3) for v in state.motor_temp_c),
                       pack_current_a=tuple(round(float(c), 3) for c in cruise_current))
    wps = tuple(Waypoint(n, e, no, a, reward=r) for n, e, no, a, r in TABLE3_WAYPOINTS if 3 <= n <= n_waypoints)
    collected = sum(r for n, *_, r in TABLE3_WAYPOINTS if n < 3)
    return Scenario(
        name=f"table3_{n_waypoints}", home=TABLE3_HOME, start=start, waypoints=wps, faults=(TABLE3_FAULT,),
        limits=TABLE3_LIMITS, params=params if isinstance(params, str) else params.to_dict(),
        reward_collected=collected, visited=(1, 2),
        description=(f"Table III kind: waypoints 1..{n_waypoints}, aft motor loses {TABLE3_FAULT.magnitude:.0%} of "
                     "its power half way from waypoint 2 to 3; plan over the waypoints not yet visited"))


def preflight_scenario(n_waypoints: int = 10, params: str | ParameterSet = "paper_si") -> Scenario:
    """All ten waypoints free, the same fault known before take-off (a harder search: 10 free
    waypoints, used by the benchmark for the planners' scaling)."""
    t0 = TABLE3_HOME.ground_temp_c
    start = StartState(east_m=0.0, north_m=0.0, alt_m=0.0, pack_temp_c=(t0,) * 4, motor_temp_c=(t0,) * 2,
                       pack_soc=(1.0,) * 4)
    wps = tuple(Waypoint(n, e, no, a, reward=r) for n, e, no, a, r in TABLE3_WAYPOINTS if n <= n_waypoints)
    return Scenario(name=f"preflight_{n_waypoints}", home=TABLE3_HOME, start=start, waypoints=wps,
                    faults=(TABLE3_FAULT,), limits=TABLE3_LIMITS,
                    params=params if isinstance(params, str) else params.to_dict(),
                    description=f"waypoints 1..{n_waypoints} all free, aft motor fault known before take-off")


def random_field_scenario(n_waypoints: int = 12, seed: int = 101, params: str | ParameterSet = "paper_si") -> Scenario:
    """``n_waypoints`` random waypoints in the same 10 km square (seeded), the Table III vehicle,
    fault and limits, all free from take-off: a scaling case for the exact search."""
    base = preflight_scenario(len(TABLE3_WAYPOINTS), params)
    rng = np.random.default_rng(seed)
    wps = tuple(Waypoint(i + 1, float(rng.uniform(-5000, 5000)), float(rng.uniform(-5000, 5000)),
                         float(rng.choice([100.0, 150.0])), float(rng.integers(20, 90))) for i in range(n_waypoints))
    return Scenario(name=f"random{n_waypoints}_{seed}", home=base.home, start=base.start, waypoints=wps,
                    faults=base.faults, limits=base.limits, params=base.params,
                    description=f"{n_waypoints} random waypoints (seed {seed}), aft motor fault known before take-off")
