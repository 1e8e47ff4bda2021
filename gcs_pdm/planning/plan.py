"""What every planner returns: the chosen route and the vehicle simulator's verdict on it."""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np

from gcs_pdm.models.params import MOTOR_NAMES, PACK_NAMES
from gcs_pdm.planning.simulator import DEFAULT_THETA, FAILURE_NAMES, VehicleSimulator


@dataclass(frozen=True)
class Plan:
    """A route (waypoint indices into ``scenario.waypoints``, in flying order) and its verdict,
    always from a whole-route simulation (``VehicleSimulator.evaluate``) of the planner's model."""

    planner: str
    route: tuple[int, ...]
    numbers: tuple[int, ...]          # the waypoints' own numbers, in flying order
    reward: float                     # scored reward (0 when the route cannot get home)
    reward_reached: float
    health_cost: float
    power_cost_mj: float
    objective: float
    feasible: bool
    failure: str                      # "none" or the cause
    fail_leg: int                     # -1, or the leg that fails (len(route) = the way home)
    flight_time_s: float
    final_soc: tuple[float, ...]
    final_pack_temp_c: tuple[float, ...]
    final_motor_temp_c: tuple[float, ...]
    leg_airspeed_mps: tuple[float, ...] = ()
    stats: dict[str, Any] = field(default_factory=dict)
    #: what the rows of final_soc/final_*_temp_c are (the simulator's packs and motors)
    pack_names: tuple[str, ...] = PACK_NAMES
    motor_names: tuple[str, ...] = MOTOR_NAMES

    def to_dict(self) -> dict[str, Any]:
        d = {k: getattr(self, k) for k in self.__dataclass_fields__}
        d["route"] = list(self.route)
        d["numbers"] = list(self.numbers)
        packs, motors = d.pop("pack_names"), d.pop("motor_names")
        d["final_soc"] = dict(zip(packs, self.final_soc))
        d["final_pack_temp_c"] = dict(zip(packs, self.final_pack_temp_c))
        d["final_motor_temp_c"] = dict(zip(motors, self.final_motor_temp_c))
        d["leg_airspeed_mps"] = list(self.leg_airspeed_mps)
        return d


def make_plan(sim: VehicleSimulator, route: Sequence[int], planner: str, theta: Sequence[float] = DEFAULT_THETA,
              **stats: Any) -> Plan:
    route = tuple(int(r) for r in route)
    ev = sim.evaluate([route])
    nodes = [sim.start_node, *route, sim.landing_node]
    speeds = tuple(float(sim.legs.airspeed[a, b]) for a, b in zip(nodes[:-1], nodes[1:]))
    return Plan(
        planner=planner, route=route, numbers=tuple(sim.scenario.waypoints[i].number for i in route),
        reward=float(ev.reward[0]), reward_reached=float(ev.reward_reached[0]),
        health_cost=float(ev.health_cost[0]), power_cost_mj=float(ev.power_cost[0]),
        objective=float(ev.objective(theta)[0]), feasible=bool(ev.feasible[0]),
        failure=FAILURE_NAMES[int(ev.cause[0])], fail_leg=int(ev.fail_leg[0]), flight_time_s=float(ev.flight_time_s[0]),
        final_soc=tuple(float(v) for v in ev.final_soc[0]),
        final_pack_temp_c=tuple(float(v) for v in ev.final_pack_temp[0]),
        final_motor_temp_c=tuple(float(v) for v in ev.final_motor_temp[0]),
        leg_airspeed_mps=speeds, stats=dict(stats), pack_names=tuple(sim.pack_names),
        motor_names=tuple(sim.motor_names))


def better(reward_a: float, obj_a: float, reward_b: float, obj_b: float, tol: float = 1e-9) -> bool:
    """Lexicographic: more reward, then a higher objective (lower costs)."""
    if reward_a > reward_b + tol:
        return True
    return abs(reward_a - reward_b) <= tol and obj_a > obj_b + tol


def rank(reward: np.ndarray, objective: np.ndarray) -> int:
    """Index of the best candidate by (reward, objective)."""
    order = np.lexsort((-objective, -reward))
    return int(order[0])
