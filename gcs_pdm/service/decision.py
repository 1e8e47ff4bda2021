"""The decision maker's rules, pure: which waypoints are left, which candidate route to fly, and
the mission items that fly it. No I/O, no clocks: the live loop calls these with plain values.

Rules (docs/service.md):

* candidates are the planner's route, the rest of the current mission in its order ("keep") and
  the direct return to the landing site ("home");
* a candidate the vehicle simulator predicts to fail is never chosen while a feasible one exists;
* among feasible ones the highest objective wins; a tie keeps the current mission (an upload is
  not free: it is a moment of risk on a lossy link);
* if none is feasible, the one that reaches the most reward before its predicted failure is
  proposed, flagged ``feasible: false``, and never uploaded in ``auto`` mode without an operator.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Sequence

from gcs_pdm import missions as M
from gcs_pdm.geo import EARTH_RADIUS_M

#: a mission waypoint within this distance of a catalogue waypoint is that waypoint
MATCH_RADIUS_M = 30.0


@dataclass(frozen=True)
class CatalogueWaypoint:
    """A place the operator wants visited, with its reward (the planner's ``Waypoint``, in degrees)."""

    number: int
    lat_deg: float
    lon_deg: float
    alt_m: float
    reward: float
    airspeed_mps: float = 25.0


@dataclass(frozen=True)
class Candidate:
    name: str                   # planner | keep | home
    route: tuple[int, ...]      # catalogue waypoint numbers in flying order
    feasible: bool
    reward: float               # scored reward (0 when infeasible)
    reward_reached: float       # reward reached before a predicted failure
    objective: float
    cause: str | None = None
    extra: dict[str, Any] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        return {"name": self.name, "route": list(self.route), "feasible": self.feasible, "reward": self.reward,
                "reward_reached": self.reward_reached, "objective": self.objective, "cause": self.cause, **self.extra}


def distance_m(lat1: float, lon1: float, lat2: float, lon2: float) -> float:
    p1, p2 = math.radians(lat1), math.radians(lat2)
    dp, dl = p2 - p1, math.radians(lon2 - lon1)
    a = math.sin(dp / 2) ** 2 + math.cos(p1) * math.cos(p2) * math.sin(dl / 2) ** 2
    return 2 * EARTH_RADIUS_M * math.asin(min(1.0, math.sqrt(a)))


def is_nav_waypoint(item: M.MissionItem) -> bool:
    return item.command == M.MAV_CMD_NAV_WAYPOINT and item.frame in M.GLOBAL_FRAMES


def match_items(items: Sequence[M.MissionItem], catalogue: Sequence[CatalogueWaypoint],
                radius_m: float = MATCH_RADIUS_M) -> dict[int, int]:
    """Mission seq -> catalogue number for every NAV_WAYPOINT item that lies on a catalogue waypoint."""
    out: dict[int, int] = {}
    for item in items:
        if not is_nav_waypoint(item) or item.seq == 0:  # seq 0 is ArduPilot's home
            continue
        best = min(catalogue, key=lambda w: distance_m(item.lat_deg, item.lon_deg, w.lat_deg, w.lon_deg), default=None)
        if best is not None and distance_m(item.lat_deg, item.lon_deg, best.lat_deg, best.lon_deg) <= radius_m:
            out[item.seq] = best.number
    return out


def catalogue_from_items(items: Sequence[M.MissionItem], reward: float = 1.0) -> list[CatalogueWaypoint]:
    """With no rewards configured, every waypoint of the vehicle's mission is worth ``reward``."""
    return [CatalogueWaypoint(number=i + 1, lat_deg=it.lat_deg, lon_deg=it.lon_deg, alt_m=float(it.z), reward=reward)
            for i, it in enumerate(x for x in items if is_nav_waypoint(x) and x.seq != 0)]


def remaining_route(items: Sequence[M.MissionItem], current_seq: int | None, catalogue: Sequence[CatalogueWaypoint],
                    visited: set[int]) -> list[int]:
    """Catalogue numbers the current mission still flies to, in its order (from ``current_seq`` on)."""
    seq_to_number = match_items(items, catalogue)
    start = current_seq if current_seq is not None else 0
    route: list[int] = []
    for item in items:
        n = seq_to_number.get(item.seq)
        if item.seq >= start and n is not None and n not in visited and n not in route:
            route.append(n)
    return route


def choose(candidates: Sequence[Candidate]) -> tuple[Candidate, str]:
    """The candidate to fly and why (see the module docstring)."""
    if not candidates:
        raise ValueError("candidates: nothing to choose from")
    feasible = [c for c in candidates if c.feasible]
    if feasible:
        best = max(feasible, key=lambda c: (round(c.objective, 9), c.name == "keep"))
        keep = next((c for c in feasible if c.name == "keep"), None)
        if keep is not None and keep.objective >= best.objective - 1e-9:
            return keep, "the current mission is predicted to succeed and nothing scores better"
        return best, f"{best.name} is feasible with the best objective {best.objective:.3f}"
    best = max(candidates, key=lambda c: (c.reward_reached, c.name == "home"))
    keep = next((c for c in candidates if c.name == "keep"), None)
    if keep is not None and tuple(keep.route) == tuple(best.route) and keep.reward_reached >= best.reward_reached:
        # the best of the infeasible flies the current mission's own route (typically "home" once
        # every waypoint is visited): there is nothing to upload, only an operator to alert
        best = keep
    return best, "no candidate is predicted to get home inside the limits; operator decision needed"


def route_of_items(items: Sequence[M.MissionItem], catalogue: Sequence[CatalogueWaypoint]) -> list[int]:
    seq_to_number = match_items(items, catalogue)
    return [seq_to_number[i.seq] for i in items if i.seq in seq_to_number]


# --- decisions that do not go stale (issue 31, part 4) ---------------------------------------------

@dataclass(frozen=True)
class ProposalGate:
    """Whether an operator may decide on a proposal now, and whether it is still the decision.

    ``blocked``: Approve and Reject are refused (``reason`` says why: the link is lost, the vehicle
    failed or is on the ground): deciding on a vehicle one cannot reach or that no longer flies acts
    on a state the service cannot support. ``stale``: the proposal was made from a state older than
    ``reevaluate_every_s``, or under other faults than now: Approve re-plans first, from the current
    state, and shows the new proposal instead of uploading this one."""

    age_s: float | None
    blocked: bool
    stale: bool
    reason: str | None

    def to_dict(self) -> dict[str, Any]:
        return {"age_s": None if self.age_s is None else round(self.age_s, 1), "blocked": self.blocked,
                "stale": self.stale, "reason": self.reason}


def proposal_gate(plan_time_s: float | None, now_s: float | None, *, reevaluate_every_s: float,
                  link_lost: str | None = None, failed: str | None = None, flying: bool = True,
                  not_flying_reason: str = "", plan_faults: Sequence[Any] = (),
                  faults_now: Sequence[Any] = ()) -> ProposalGate:
    age = None if plan_time_s is None or now_s is None else max(0.0, float(now_s) - float(plan_time_s))
    if link_lost is not None:
        return ProposalGate(age, True, False, f"link lost: {link_lost}")
    if failed:
        return ProposalGate(age, True, False, f"the vehicle has failed: {failed}")
    if not flying:
        return ProposalGate(age, True, False, f"the vehicle is not flying: {not_flying_reason or 'landed'}")
    if not _same_faults(plan_faults, faults_now):
        return ProposalGate(age, False, True, "the faults changed since it was planned: Approve re-plans first")
    if age is not None and age > reevaluate_every_s:
        return ProposalGate(age, False, True,
                            f"{age:.0f} s old (re-evaluated every {reevaluate_every_s:g} s): Approve re-plans first")
    return ProposalGate(age, False, False, None)


#: a fault's magnitude may move this much (the diagnoser refines it) before a proposal is stale
FAULT_MAGNITUDE_TOLERANCE = 0.05


def _same_faults(a: Sequence[Any], b: Sequence[Any]) -> bool:
    """The same motors faulted, each magnitude within FAULT_MAGNITUDE_TOLERANCE (MotorFaults or dicts)."""
    def by_motor(faults):
        out: dict[str, float] = {}
        for f in faults:
            motor = f.get("motor") if isinstance(f, dict) else getattr(f, "motor", None)
            mag = f.get("magnitude", 0.0) if isinstance(f, dict) else getattr(f, "magnitude", 0.0)
            out[str(motor)] = max(out.get(str(motor), 0.0), float(mag))
        return out
    x, y = by_motor(a), by_motor(b)
    return x.keys() == y.keys() and all(abs(x[k] - y[k]) <= FAULT_MAGNITUDE_TOLERANCE for k in x)


def outlook_alarm(outlook: dict[str, Any] | None, *, max_failure_probability: float,
                  reserve_soc: float) -> dict[str, Any] | None:
    """The alarm for the vehicle-level outlook (``/status.outlook``): ``critical`` when P(failure)
    is above ε, ``warning`` when the landing forecast (p05 of the lowest pack's landing SoC) is
    below the reserve; None when neither (or the outlook is unknown: said there, not alarmed)."""
    if not outlook or outlook.get("unknown"):
        return None
    p_fail = float(outlook.get("p_failure", 0.0))
    p05 = outlook.get("landing_soc_p05")
    if p_fail > max_failure_probability:
        return {"kind": "landing_forecast", "level": "critical", "title": "Vehicle may not get home",
                "text": f"P(failure) {p_fail:.0%} > {max_failure_probability:.0%} on the current mission; replanning",
                "statustext": f"PDM: P(fail) {p_fail:.0%} > {max_failure_probability:.0%}: REPLAN/RTL?"}
    if p05 is not None and float(p05) < reserve_soc:
        return {"kind": "landing_forecast", "level": "critical", "title": "Landing forecast below the reserve",
                "text": f"lowest pack lands at {float(p05):.0%} (p05) < reserve {reserve_soc:.0%}; replanning",
                "statustext": f"PDM: landing {float(p05):.0%} (p05) < reserve {reserve_soc:.0%}: REPLAN",
                "severity": "warning"}
    return None


def outlook_line(outlook: dict[str, Any] | None) -> str:
    """The vehicle-level line the console always shows."""
    if not outlook:
        return "outlook unknown: not evaluated yet"
    if outlook.get("unknown"):
        return f"outlook unknown: {outlook['unknown']}"
    return (f"gets home with {outlook['landing_soc_p50']:.0%} ({outlook['landing_soc_p05']:.0%}–"
            f"{outlook['landing_soc_p95']:.0%}), P(failure) {failure_probability_text(outlook['p_failure'], outlook.get('samples'))}")


def failure_probability_text(p_failure: float, samples: int | None) -> str:
    """A Monte Carlo P(failure) as text. No failing draw among n is not "0 %": it says the
    probability is below the 95 % upper bound that n clean draws support, 1 − 0.05^(1/n) (1.5 % of
    200; measured on simulated routes: such routes failed 0.026 % of the time,
    docs/notes/2026-11-27-failure-reliability.md)."""
    if p_failure == 0.0 and samples:
        return f"< {1.0 - 0.05 ** (1.0 / samples):.1%} (0 of {samples} draws failed)"
    return f"{p_failure:.1%}"
