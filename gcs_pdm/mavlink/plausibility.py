"""Physical plausibility of telemetry: values no configured vehicle can produce become missing.

Every frame the link or a replay makes passes through a :class:`FrameGate` (in
:class:`~gcs_pdm.mavlink.mapping.FrameMapper`), so no consumer ever sees 101 V on a 21 V pack or
1e69 °C. A gated value becomes ``None`` (the frames' "not available") and is counted per
``(frame kind, field, reason)``; the counts are in ``FrameMapper.stats`` and in ``/status``.

The :class:`PhysicalEnvelope` is plain data. Today it is built from the active parameter set
(each pack's full-charge voltage ``q_max / C_b`` gives its cells in series); a vehicle description
with packs (cells in series) and limits can build it through :meth:`PhysicalEnvelope.from_packs`.
"""
from __future__ import annotations

import dataclasses
import math
from collections import Counter
from dataclasses import dataclass, field
from functools import lru_cache
from typing import Mapping

from gcs_pdm.frames import FRAME_KIND_OF

# Lithium cells: below 2.5 V a cell is destroyed, 4.35 V is the highest charge voltage of any
# common chemistry (LiHV). The margin covers sensor error and voltage spikes under regeneration.
CELL_MIN_V = 2.5
CELL_MAX_V = 4.35
VOLTAGE_MARGIN = 0.05
# A charged LiPo cell, to count the cells of a pack from its full-charge voltage.
CELL_FULL_V = 4.2

Range = tuple[float, float]


@dataclass(frozen=True)
class PhysicalEnvelope:
    """What the vehicle can physically report; anything outside is a sensor or link fault (or a lie)."""

    pack_voltage_v: Mapping[str, Range]  # per pack name
    pack_current_a: Range = (-50.0, 300.0)  # negative: charging/regeneration
    motor_current_a: Range = (-5.0, 300.0)
    motor_rpm: Range = (0.0, 40_000.0)
    temperature_c: Range = (-40.0, 100.0)  # packs, motors, ambient air
    airspeed_mps: Range = (0.0, 150.0)
    latitude_deg: Range = (-90.0, 90.0)
    longitude_deg: Range = (-180.0, 180.0)
    altitude_m: Range = (-500.0, 12_000.0)

    @classmethod
    def from_packs(cls, cells_in_series: Mapping[str, int], **limits) -> "PhysicalEnvelope":
        """From each pack's cells in series (a vehicle description); ``limits`` override the rest."""
        ranges = {name: (n * CELL_MIN_V * (1 - VOLTAGE_MARGIN), n * CELL_MAX_V * (1 + VOLTAGE_MARGIN))
                  for name, n in cells_in_series.items()}
        return cls(pack_voltage_v=ranges, **limits)

    @classmethod
    def from_parameter_set(cls, params, **limits) -> "PhysicalEnvelope":
        """From a :class:`~gcs_pdm.models.params.ParameterSet`: full voltage q_max/C_b -> cells."""
        cells = {name: max(1, round(p.battery.q_max / p.battery.C_b / CELL_FULL_V))
                 for name, p in params.packs.items()}
        return cls.from_packs(cells, **limits)

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


@lru_cache(maxsize=1)
def default_envelope() -> PhysicalEnvelope:
    """The envelope of the default parameter set (replay and tests without a service)."""
    from gcs_pdm.models.params import default_set

    return PhysicalEnvelope.from_parameter_set(default_set())


def _checks(env: PhysicalEnvelope) -> dict[str, dict[str, Range | Mapping[str, Range]]]:
    """frame kind -> field -> range (a mapping: per key, e.g. per pack)."""
    return {
        "pack": {"voltage_v": env.pack_voltage_v, "current_a": env.pack_current_a,
                 "temperature_c": env.temperature_c},
        "motor": {"current_a": env.motor_current_a, "rpm": env.motor_rpm, "temperature_c": env.temperature_c},
        "ambient": {"temperature_c": env.temperature_c},
        "position": {"lat_deg": env.latitude_deg, "lon_deg": env.longitude_deg, "alt_m": env.altitude_m},
        "airdata": {"airspeed": env.airspeed_mps, "groundspeed": env.airspeed_mps},
    }


@dataclass
class FrameGate:
    """Replaces implausible values by None and counts them."""

    envelope: PhysicalEnvelope
    gated: Counter = field(default_factory=Counter)  # (kind, field, reason) -> count
    _by_class: dict = field(init=False, repr=False)

    def __post_init__(self) -> None:
        # frame class -> (kind, ((field, range or per-key ranges, per key?), ...)), resolved once
        checks = _checks(self.envelope)
        self._by_class = {cls: (kind, tuple((name, allowed, isinstance(allowed, Mapping))
                                            for name, allowed in checks.get(kind, {}).items()))
                          for cls, kind in FRAME_KIND_OF.items()}

    def __call__(self, frame):
        kind, checks = self._by_class.get(type(frame), (None, ()))
        changes = None
        for name, allowed, per_key in checks:
            value = getattr(frame, name)
            if value is None:
                continue
            if per_key:
                allowed = allowed.get(getattr(frame, kind, None))
                if allowed is None:
                    continue
            if allowed[0] <= value <= allowed[1]:  # the common case; NaN fails it
                continue
            reason = "not_finite" if not math.isfinite(value) else (
                "below_range" if value < allowed[0] else "above_range")
            if changes is None:
                changes = {}
            changes[name] = None
            self.gated[(kind, name, reason)] += 1
        return dataclasses.replace(frame, **changes) if changes else frame

    def ranges_for(self, cls: type, key) -> tuple[tuple[str, float, float], ...]:
        """The (field, low, high) checks :meth:`__call__` makes on a frame of class ``cls`` whose key
        field (``pack``/``motor``) is ``key``: a frame whose checked values are all None or within
        them passes unchanged, so the frame mapping can test them where it builds the frame."""
        kind, checks = self._by_class.get(cls, (None, ()))
        out = []
        for name, allowed, per_key in checks:
            if per_key:
                allowed = allowed.get(key)
                if allowed is None:
                    continue
            out.append((name, allowed[0], allowed[1]))
        return tuple(out)

    def counts(self) -> dict[str, int]:
        """``{"pack.voltage_v.above_range": 3, ...}``"""
        return {f"{k}.{f}.{r}": n for (k, f, r), n in sorted(self.gated.items())}
