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

Trust (docs/operations.md, "Safety"): one timestamp never moves message time. A sample more than
``MAX_STEP_S`` ahead of the accepted time, or more than ``REBOOT_BACKSTEP_S`` behind it, is only a
*candidate*; it is adopted when ``CONFIRM_SAMPLES`` consecutive timed messages agree with it over at
least ``CONFIRM_SPAN_S`` of receive time — from at least ``CONFIRM_TYPES`` message types, or from any
type when time went back to near zero (a reboot). A sample consistent with the accepted time resets
the candidate, so a sender injecting odd timestamps between the vehicle's own never wins while the
vehicle is heard, however fast it floods (the vehicle's timed streams run at several Hz). Everything else is
counted in ``rejected`` and its message gives no frame. The first time is acquired the same way.
Held against receive time: a sample is taken at once only if it is at most ``HOLD_STEP_S`` plus
``MAX_RATE`` times the receive time since the last accepted sample ahead of the accepted time (a
short outage, a vehicle or simulator running faster than real time, all pass: their time moves by
small steps, or by about the receive time that passed). A larger step is a candidate under the rules
above. An unsigned sender that puts one packet 9.9 s ahead between the vehicle's own therefore never
moves message time: its step is not followed by the vehicle's next sample, which agrees with the old
time. Such unfollowed steps — steps only some sender makes — are counted; ``SUSPECT_STEPS`` of them
within ``SUSPECT_WINDOW_S`` of receive time raise ``spoof_suspected`` (a warning, /health degraded).
What is left: a sender that floods agreeing samples of several types for ``CONFIRM_SPAN_S`` while the
vehicle is silent can still move time; only MAVLink signing stops that (docs/operations.md, "Safety").
"""
from __future__ import annotations

import enum
import logging
from collections import deque

log = logging.getLogger(__name__)


class Verdict(enum.Enum):
    """Why ``on_time_boot`` gave no time."""

    FALLBACK = "fallback"  # the clock runs on receive time
    ACQUIRING = "acquiring"  # no time adopted yet: hold the frame
    REJECTED = "rejected"  # the timestamp disagrees with the vehicle's accepted time: drop the frame


class _Candidate:
    __slots__ = ("first_boot_s", "first_recv_s", "latest_boot_s", "types", "count")

    def __init__(self, boot_s: float, recv_s: float, msgid):
        self.first_boot_s = self.latest_boot_s = boot_s
        self.first_recv_s = recv_s
        self.types = {msgid}
        self.count = 1


class RateWatch:
    """Message time against receive time, one window of ``WINDOW_S`` receive seconds at a time. A
    vehicle's clock runs at real time; the first ``BASELINE_WINDOWS`` windows measure the pace, and
    only a pace within ``REAL_TIME`` is judged: a simulator faster than real time paces itself by a
    wall clock it falls behind and catches up with (and waits in lockstep), so its windows vary and
    say nothing. On real time, a window running more than ``RATE_CHANGE`` times faster is a clock
    someone else is moving (small steps ahead, each within what the step rule takes at once):
    ``suspected`` until a window is back in line. (Slower windows are stalls: a spoofer moves time
    forward; back-steps have their own rules.)"""

    WINDOW_S = 10.0
    BASELINE_WINDOWS = 3
    RATE_CHANGE = 1.5
    REAL_TIME = (0.8, 1.25)

    def __init__(self):
        self._start: tuple[float, float] | None = None
        self._first: list[float] = []
        self.baseline: float | None = None
        self.latest: float | None = None
        self.suspected = False
        self.off_windows = 0

    def __eq__(self, other) -> bool:  # two clocks fed the same samples agree (tests compare them whole)
        return isinstance(other, RateWatch) and vars(self) == vars(other)

    def __repr__(self) -> str:
        return f"RateWatch({vars(self)})"

    def note_many(self, recv_s, t) -> bool:
        """:meth:`note` of each sample in turn (numpy arrays), visiting only those that close a
        window; whether any closed off its pace."""
        import numpy as np

        n = len(recv_s)
        k, flagged = 0, False
        if n and self._start is None:
            self._start = (float(recv_s[0]), float(t[0]))
            k = 1
        # the first sample at or past a window's end is the first whose running maximum is
        reach = np.maximum.accumulate(recv_s)
        while k < n:
            j = k + int(np.searchsorted(reach[k:], self._start[0] + self.WINDOW_S, side="left"))
            if j >= n:
                break
            flagged |= self.note(float(recv_s[j]), float(t[j]))
            k = j + 1
        return flagged

    def note(self, recv_s: float, t: float) -> bool:
        """An accepted sample (receive time, message time); True when a window closed off its rate."""
        if self._start is None:
            self._start = (recv_s, t)
            return False
        span = recv_s - self._start[0]
        if span < self.WINDOW_S:
            return False
        rate = (t - self._start[1]) / span
        self._start = (recv_s, t)
        self.latest = rate
        if self.baseline is None:
            self._first.append(rate)
            if len(self._first) == self.BASELINE_WINDOWS:
                self.baseline = sorted(self._first)[self.BASELINE_WINDOWS // 2]
            return False
        if not self.REAL_TIME[0] <= self.baseline <= self.REAL_TIME[1]:
            return False
        self.suspected = rate > self.baseline * self.RATE_CHANGE
        self.off_windows += self.suspected
        return self.suspected


class VehicleClock:
    # time_boot_ms going back by more than this is a reboot (or a lie), not reordering between streams.
    REBOOT_BACKSTEP_S = 2.0
    # Consecutive vehicle timestamps further apart than this are a jump to be confirmed (a link
    # outage, a reboot, or a hostile packet); the vehicle's timed streams run at >= 1 Hz.
    MAX_STEP_S = 10.0
    CONFIRM_SAMPLES = 4
    CONFIRM_TYPES = 2
    CONFIRM_SPAN_S = 2.0
    # The first time is adopted from this many consecutive agreeing samples (so one odd packet
    # before the vehicle's own cannot set it); frames wait meanwhile and are dated afterwards.
    ACQUIRE_SAMPLES = 2
    # A reboot is evident when time goes back to below this.
    NEAR_BOOT_S = 120.0
    # A forward step taken at once: this much, plus MAX_RATE times the receive time since the last
    # accepted sample (a larger step waits for confirmation as a jump does).
    HOLD_STEP_S = 2.0
    MAX_RATE = 1.5
    # Forward steps abandoned because the next sample agreed with the old time, this many within
    # this much receive time: someone else is sending the vehicle's timestamps.
    SUSPECT_STEPS = 3
    SUSPECT_WINDOW_S = 60.0
    _REJECT_MESSAGE = "vehicle time_boot_ms %.3f s disagrees with the vehicle's time %.3f s: ignored (%d so far)"
    _BACK_MESSAGE = "vehicle rebooted (time_boot_ms %.3f s -> %.3f s); time continues at %.3f s"
    _JUMP_MESSAGE = "vehicle time jumped %.3f s -> %.3f s (confirmed by %d messages of %d types)"

    def __init__(self, sync_window_s: float = 30.0):
        self.sync_window_s = sync_window_s
        self.synced = False
        self.fallback = False
        self.now: float | None = None  # latest vehicle time (s), epoch-adjusted
        self.epoch_s = 0.0
        self.reboots = 0
        self.jumps = 0  # forward jumps adopted (after a link outage)
        self.rejected = 0  # timestamps that did not move message time
        self._last_boot_s: float | None = None
        self._last_timed_recv_s: float | None = None
        self._first_recv_s: float | None = None
        self._candidate: _Candidate | None = None
        self._receive: _ReceiveClock | None = None  # after the fallback: receive time under the same rules
        self.accepted = 0  # timestamps that gave message time (the vehicle's timed stream is alive)
        self.unfollowed_steps = 0  # forward steps the next sample did not follow
        self._unfollowed_at: deque[float] = deque(maxlen=self.SUSPECT_STEPS)
        self._suspect_warned = False
        self.rate = RateWatch()
        self._rate_warned = False

    def _note_rate(self, recv_s: float, flagged: bool | None = None) -> None:
        if flagged is None:
            flagged = self.rate.note(recv_s, self.now)
        if flagged and not self._rate_warned:
            self._rate_warned = True
            log.warning("vehicle clock ran at %.2fx receive time over %.0f s, its usual pace %.2fx: another "
                        "sender may be moving it (only signing stops this)", self.rate.latest, self.rate.WINDOW_S,
                        self.rate.baseline)

    @property
    def spoof_suspected(self) -> bool:
        """Whether ``SUSPECT_STEPS`` steps ahead went unfollowed within ``SUSPECT_WINDOW_S`` of the
        latest receive time (someone besides the vehicle sends its timestamps)."""
        at = self._unfollowed_at
        return (len(at) == self.SUSPECT_STEPS and self._last_timed_recv_s is not None
                and self._last_timed_recv_s - at[0] <= self.SUSPECT_WINDOW_S)

    def to_dict(self) -> dict:
        out = {"synced": self.synced, "fallback": self.fallback, "now_s": self.now, "reboots": self.reboots,
               "jumps": self.jumps, "rejected": self.rejected, "unfollowed_steps": self.unfollowed_steps,
               "spoof_suspected": self.spoof_suspected,
               "rate": {"latest": self.rate.latest, "baseline": self.rate.baseline, "suspected": self.rate.suspected,
                        "off_windows": self.rate.off_windows}}
        reasons = []
        if out["spoof_suspected"]:
            reasons.append(f"{self.SUSPECT_STEPS} timestamps within {self.SUSPECT_WINDOW_S:g} s jumped ahead "
                           "of the vehicle's time and its next message did not follow: another sender "
                           "uses the vehicle's ids (time held; sign the link)")
        if self.rate.suspected:
            reasons.append(f"message time ran at {self.rate.latest:.2f}x receive time over the last "
                           f"{self.rate.WINDOW_S:g} s, the vehicle's pace is {self.rate.baseline:.2f}x: another "
                           "sender may be moving its clock (sign the link)")
        if reasons:
            out["spoof_suspected"] = True
            out["spoof_reason"] = "; ".join(reasons)
        return out

    def _allowed_step(self, recv_s: float) -> float:
        """How far ahead of the accepted time a sample received at ``recv_s`` is taken at once."""
        gap = recv_s - self._last_timed_recv_s if self._last_timed_recv_s is not None else 0.0
        return min(self.MAX_STEP_S, self.HOLD_STEP_S + max(0.0, gap) * self.MAX_RATE)

    def _abandon_candidate(self, recv_s: float) -> None:
        """A sample agreed with the accepted time: a candidate ahead of it was a step no one followed."""
        c = self._candidate
        self._candidate = None
        if c is None or self._last_boot_s is None or c.first_boot_s <= self._last_boot_s:
            return
        self.unfollowed_steps += 1
        self._unfollowed_at.append(recv_s)
        if self.spoof_suspected and not self._suspect_warned:
            self._suspect_warned = True
            log.warning("vehicle clock: %d timestamps jumped ahead and the vehicle's own did not follow; another "
                        "sender uses its ids (message time held at the vehicle's; only signing stops this)",
                        self.SUSPECT_STEPS)

    def _consistent(self, boot_s: float, ref_s: float) -> bool:
        return ref_s - self.REBOOT_BACKSTEP_S <= boot_s <= ref_s + self.MAX_STEP_S

    def agrees(self, boot_s: float) -> bool:
        """Whether a ``time_boot_ms`` (s) agrees with the accepted vehicle time."""
        return self._last_boot_s is not None and self._consistent(boot_s, self._last_boot_s)

    def _note_candidate(self, boot_s: float, recv_s: float, msgid) -> _Candidate:
        c = self._candidate
        if c is not None and self._consistent(boot_s, c.latest_boot_s):
            c.count += 1
            c.types.add(msgid)
            c.latest_boot_s = max(c.latest_boot_s, boot_s)
        else:
            c = self._candidate = _Candidate(boot_s, recv_s, msgid)
        return c

    def _reject(self, boot_s: float) -> Verdict:
        self.rejected += 1
        if self.rejected in (1, 10, 100) or self.rejected % 1000 == 0:
            log.warning(self._REJECT_MESSAGE, boot_s, self._last_boot_s or 0.0, self.rejected)
        return Verdict.REJECTED

    def on_time_boot(self, boot_s: float, recv_s: float, msgid=None) -> float | Verdict:
        """A message carrying ``time_boot_ms`` arrived: its message time, or why it has none."""
        if self.fallback:
            return Verdict.FALLBACK
        last = self._last_boot_s
        if last is not None and self._consistent(boot_s, last) and boot_s <= last + self._allowed_step(recv_s):
            if self._candidate is not None:
                self._abandon_candidate(recv_s)
            if boot_s > last:
                self._last_boot_s = boot_s
        else:
            c = self._note_candidate(boot_s, recv_s, msgid)
            if last is None:
                if c.count < self.ACQUIRE_SAMPLES:
                    return Verdict.ACQUIRING
            elif c.count < self.CONFIRM_SAMPLES or recv_s - c.first_recv_s < self.CONFIRM_SPAN_S:
                return self._reject(boot_s)
            if last is not None:
                back = c.first_boot_s < last
                if len(c.types) < self.CONFIRM_TYPES and not (back and c.first_boot_s < self.NEAR_BOOT_S):
                    return self._reject(boot_s)
                if back:
                    gap = max(0.0, c.first_recv_s - (self._last_timed_recv_s or c.first_recv_s))
                    self.epoch_s = (self.now or 0.0) + gap - c.first_boot_s
                    self.reboots += 1
                    log.warning(self._BACK_MESSAGE, last, c.first_boot_s, c.first_boot_s + self.epoch_s)
                else:
                    self.jumps += 1
                    log.warning(self._JUMP_MESSAGE, last, c.first_boot_s, c.count, len(c.types))
            self._last_boot_s = c.latest_boot_s
            self._candidate = None
        t = boot_s + self.epoch_s
        if self.now is None or t > self.now:
            self.now = t
        self._last_timed_recv_s = recv_s
        self.synced = True
        self.accepted += 1
        self._note_rate(recv_s)
        return t

    def on_time_boots(self, boot_s, recv_s, msgids):
        """:meth:`on_time_boot` of many timed messages in turn (numpy arrays) on a clock that has
        its time (``synced``): their message times and whether each was accepted (a synced clock
        only rejects). The usual stream — each sample consistent with the accepted time so far —
        is taken a run at a time; any other sample goes through :meth:`on_time_boot` itself."""
        import numpy as np

        if not self.synced or self.fallback:
            raise ValueError("on_time_boots needs a clock that has its time")
        n = len(boot_s)
        times = np.empty(n)
        accepted = np.ones(n, dtype=bool)
        i, window = 0, 64
        while i < n:
            last = self._last_boot_s
            seg = boot_s[i:i + window]
            rseg = recv_s[i:i + window]
            # the accepted time before each sample of a run: the latest so far (consistent samples only raise it)
            ref = np.maximum.accumulate(np.concatenate(([last], seg[:-1])))
            # ... and the receive time of the sample before it (accepted too, in a run): _allowed_step
            prev_recv = np.concatenate(([self._last_timed_recv_s if self._last_timed_recv_s is not None
                                         else rseg[0]], rseg[:-1]))
            ahead = np.minimum(self.MAX_STEP_S,
                               self.HOLD_STEP_S + np.maximum(0.0, rseg - prev_recv) * self.MAX_RATE)
            bad = np.flatnonzero(~((ref - self.REBOOT_BACKSTEP_S <= seg) & (seg <= ref + ahead)))
            run = int(bad[0]) if bad.size else seg.size
            if run:
                if self._candidate is not None:
                    self._abandon_candidate(float(rseg[0]))
                times[i:i + run] = seg[:run] + self.epoch_s
                self._last_boot_s = max(last, float(seg[:run].max()))
                # message time after each sample of the run, for the pace watch (as on_time_boot feeds it)
                after = np.maximum.accumulate(np.maximum(self.now, times[i:i + run]))
                self.now = float(after[-1])
                self._last_timed_recv_s = float(recv_s[i + run - 1])
                self.accepted += run
                self._note_rate(0.0, self.rate.note_many(rseg[:run], after))
                i += run
            window = window * 2 if not bad.size else 64
            if bad.size:  # the odd one out: the clock's own rules (candidate, reboot, jump, reject)
                t = self.on_time_boot(float(boot_s[i]), float(recv_s[i]), int(msgids[i]))
                if t.__class__ is Verdict:
                    accepted[i] = False
                    times[i] = float("nan")
                else:
                    times[i] = t
                i += 1
        return times, accepted

    def untimed(self, recv_s: float, msgid=None) -> float | Verdict | None:
        """Time for a message without a time field; None while waiting for the first timed one;
        after the fallback its receive time under the clock's rules (``receive_time``:
        ``Verdict.REJECTED`` says drop it)."""
        if self.synced:
            return self.now
        if self.fallback:
            return self.receive_time(recv_s, msgid)
        if self._first_recv_s is None:
            self._first_recv_s = recv_s
        elif recv_s - self._first_recv_s > self.sync_window_s:
            self.fallback = True
            log.warning("no time_boot_ms from the vehicle within %.1f s: stamping frames with receive time",
                        self.sync_window_s)
            return self.receive_time(recv_s, msgid)
        return None

    def receive_time(self, recv_s: float, msgid=None) -> float | Verdict:
        """After the fallback: a vehicle message's time from its receive time (the tlog stamp in a
        replay), under the vehicle time's rules — a stamp far ahead of the others or behind them (a
        damaged tlog stamp, which lies outside the packet's CRC; a wall clock stepped back) is a
        candidate, taken only when the next messages agree with it, and a step back then continues
        the time from where it was (the epoch, as after a reboot), so it never runs backwards.
        ``Verdict.REJECTED``: drop the message. Every vehicle message passes here, in order."""
        r = self._receive
        if r is None:
            r = self._receive = _ReceiveClock(recv_s)
        t = r.on_time_boot(recv_s, recv_s, msgid)
        return Verdict.REJECTED if t.__class__ is Verdict else t

    def receive_times(self, recv_s, msgids):
        """:meth:`receive_time` of many messages in turn (numpy arrays): their times and whether each
        was accepted."""
        if self._receive is None:
            raise ValueError("receive_times needs a clock that has fallen back to receive time")
        return self._receive.on_time_boots(recv_s, recv_s, msgids)


class _ReceiveClock(VehicleClock):
    """Receive time under the vehicle clock's rules (``VehicleClock.receive_time``): every message
    carries one, so one message type confirms a jump, and its own messages say what it is."""

    CONFIRM_TYPES = 1
    _REJECT_MESSAGE = "receive time %.3f s disagrees with the messages' time %.3f s: ignored (%d so far)"
    _BACK_MESSAGE = "receive time stepped back (%.3f s -> %.3f s); message time continues at %.3f s"
    _JUMP_MESSAGE = "receive time jumped %.3f s -> %.3f s (confirmed by %d messages of %d types)"

    def __init__(self, recv_s: float):
        super().__init__()
        # seeded with its first time: the fallback itself was the wait for agreement
        self._last_boot_s = self.now = self._last_timed_recv_s = recv_s
        self.synced = True
