"""The vehicle clock: message time for every frame, the same live, in replay and from a fast sim.

Policy (docs/mavlink.md, "Message time"):

* Messages that carry ``time_boot_ms`` are stamped with it (seconds), plus an epoch offset
  that only changes when the vehicle reboots, so time never runs backwards across a reboot.
* Messages without a time field (BATTERY_STATUS, ESC_TELEMETRY_1_TO_4, VFR_HUD, HEARTBEAT…)
  are stamped with the latest vehicle time seen ("hold last"). This uses no receive time at all,
  so a simulated vehicle running 10x faster than real time yields the same frame times as a
  real-time one; the price is a resolution of one period of the vehicle's timed stream.
* Until the first timed message arrives, frames wait (at most ``sync_window_s`` of receive time)
  and are then back-dated by their receive-time distance to it. If none arrives within the
  window, the clock falls back for good to receive time (the tlog timestamp in replay).
"""
from __future__ import annotations

import logging

log = logging.getLogger(__name__)


class VehicleClock:
    # time_boot_ms going back by more than this is a reboot, not reordering between streams.
    REBOOT_BACKSTEP_S = 2.0

    def __init__(self, sync_window_s: float = 30.0):
        self.sync_window_s = sync_window_s
        self.synced = False
        self.fallback = False
        self.now: float | None = None  # latest vehicle time (s), epoch-adjusted
        self.epoch_s = 0.0
        self.reboots = 0
        self._last_boot_s: float | None = None
        self._last_timed_recv_s: float | None = None
        self._first_recv_s: float | None = None

    def on_time_boot(self, boot_s: float, recv_s: float) -> float | None:
        """A message carrying ``time_boot_ms`` arrived; returns its time, or None in fallback mode."""
        if self.fallback:
            return None
        if self._last_boot_s is not None and boot_s < self._last_boot_s - self.REBOOT_BACKSTEP_S:
            gap = max(0.0, recv_s - (self._last_timed_recv_s or recv_s))
            self.epoch_s = (self.now or 0.0) + gap - boot_s
            self.reboots += 1
            log.warning("vehicle rebooted (time_boot_ms %.3f s -> %.3f s); time continues at %.3f s",
                        self._last_boot_s, boot_s, boot_s + self.epoch_s)
            self._last_boot_s = boot_s
        elif self._last_boot_s is None or boot_s > self._last_boot_s:
            self._last_boot_s = boot_s
        t = boot_s + self.epoch_s
        if self.now is None or t > self.now:
            self.now = t
        self._last_timed_recv_s = recv_s
        self.synced = True
        return t

    def untimed(self, recv_s: float) -> float | None:
        """Time for a message without a time field; None while waiting for the first timed one."""
        if self.synced:
            return self.now
        if self.fallback:
            return recv_s
        if self._first_recv_s is None:
            self._first_recv_s = recv_s
        elif recv_s - self._first_recv_s > self.sync_window_s:
            self.fallback = True
            log.warning("no time_boot_ms from the vehicle within %.1f s: stamping frames with receive time",
                        self.sync_window_s)
            return recv_s
        return None
