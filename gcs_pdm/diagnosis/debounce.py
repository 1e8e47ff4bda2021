"""Debouncing: a condition must hold for a while before a fault is raised, and its absence must
hold for a while before it clears, so noise cannot make a fault flap.

Two thresholds give hysteresis: the detector reports ``raise_condition`` (evidence strong enough
to raise) and ``clear_condition`` (evidence gone); between them an active fault simply stays.
"""
from __future__ import annotations

import math
from dataclasses import dataclass


@dataclass(frozen=True)
class DebounceConfig:
    raise_after_s: float = 3.0
    clear_after_s: float = 10.0


class Debouncer:
    def __init__(self, config: DebounceConfig = DebounceConfig()):
        self.config = config
        self.active = False
        self._since: float = math.nan      # when the pending condition started holding

    def update(self, time_s: float, raise_condition: bool, clear_condition: bool) -> str | None:
        """Returns 'raise', 'clear' or None for this observation."""
        if not self.active:
            if raise_condition:
                if math.isnan(self._since):
                    self._since = time_s
                if time_s - self._since >= self.config.raise_after_s:
                    self.active, self._since = True, math.nan
                    return "raise"
            else:
                self._since = math.nan
        else:
            if clear_condition:
                if math.isnan(self._since):
                    self._since = time_s
                if time_s - self._since >= self.config.clear_after_s:
                    self.active, self._since = False, math.nan
                    return "clear"
            else:
                self._since = math.nan
        return None

    @property
    def pending_since(self) -> float:
        return self._since
