"""One stream's place and capture time, packet after packet: which packets are corrupted, where the
stream restarted, and how many packets a gap may be said to have lost. Written once, for every
decoder and live counter (:mod:`lidarpkt.vendors.velodyne.frames`, :mod:`lidarpkt.vendors.velodyne.stream`,
:mod:`lidarpkt.vendors.ouster.frames`, :mod:`lidarpkt.vendors.ouster.stream`).

A packet's *place* is the sensor's own count of it (a VLP-16's µs past the hour, an Ouster's frame
and measurement ids), in ticks of a known duration. Between two packets the sensor's step and the
host's capture-time step agree: the sensor's may not be longer by more than :data:`INTERRUPTION_S`
(buffering), nor shorter by more than :data:`CAPTURE_STALL_S` (a stalled sender or reader delivering
late, in a burst). A step that disagrees by more is a jump no sensor makes, and a step of more than
:data:`INTERRUPTION_S` is an interruption (the sensor stopped, or the cable was out), neither of them
packets lost:

* a packet that agrees with neither the packet before it nor the one after is *corrupted*: skipped
  and counted (its own reason in :mod:`lidarpkt.core.dropped`), the stream goes on from the packet before;
* a jump after which the packets agree with each other again is a *restart* (a power cycle, a clock
  reset, an interruption, two captures back to back): counted, and the stream goes on from the new
  place, losing nothing.

Without capture times (raw payloads: host time 0) only the sensor's own step is judged.

Packets lost in a gap are never more than the capture time can hold (:meth:`StreamContinuity.bound_lost`):
the stream keeps a credit of the host time that passed, in packet periods, less the packets
received and the losses already granted; a loss is granted only out of that credit, so the losses of
a whole capture never exceed its capture time at the sensor's packet rate (plus
:data:`CAPTURE_RESOLUTION_S`, which a loss may borrow from the time after it, for capture clocks that
stamp in bursts). The credit is kept within :data:`INTERRUPTION_S` either way, so that a stall or a
burst is forgotten after a second.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: The most a stream's own clock may run ahead of or behind the capture clock between two packets
#: (kernel buffering, a stalled reader, a burst): a larger disagreement is a corrupted packet or a
#: restarted stream, never a loss. Without capture times: the longest step in the sensor's own
#: count that is taken as a gap.
INTERRUPTION_S = 1.0
_TOLERANCE_NS = int(INTERRUPTION_S * 1e9)
#: Capture time a loss may borrow from the packets after it: capture clocks stamp packets in bursts
#: as coarse as a 15.6 ms timer tick (Windows captures), so the packets around a gap may carry the
#: same time though the gap took several periods.
CAPTURE_RESOLUTION_S = 0.02
#: How much longer than the sensor's step the capture clock's may be (a stalled sender or reader
#: delivering packets late, in a burst): beyond it the capture time itself is taken as corrupted.
CAPTURE_STALL_S = 10.0
_STALL_NS = int(CAPTURE_STALL_S * 1e9)


def packets_spanned(span_ns: np.ndarray | float, period_ns: np.ndarray | float) -> np.ndarray:
    """``int64``: whole packet periods in a time span (rounded), the one conversion of capture time
    into packets that every loss bound uses."""
    return np.rint(np.asarray(span_ns, np.float64) / np.asarray(period_ns, np.float64)).astype(np.int64)


def jumps(step_ns: np.ndarray, host_step_ns: np.ndarray, host_known: np.ndarray) -> np.ndarray:
    """``bool[N]``: steps (the sensor's, ns) longer than :data:`INTERRUPTION_S`, or longer by more than
    that than the capture time between the two packets (``host_step_ns``, judged where
    ``host_known``), or shorter by more than :data:`CAPTURE_STALL_S`: an interruption, a restart or a
    corrupted packet, never a gap of lost packets."""
    step = np.asarray(step_ns, np.float64)
    ahead = np.where(host_known, step - host_step_ns, 0.0)  # the sensor claims more time than passed
    return (np.abs(step) > _TOLERANCE_NS) | (ahead > _TOLERANCE_NS) | (ahead < -_STALL_NS)


@dataclass
class Steps:
    """What :meth:`StreamContinuity.check` found in a batch (arrays of the batch's length)."""

    keep: np.ndarray  # bool[N]: False for the corrupted packets (skip them)
    restart: np.ndarray  # bool[N]: the packet starts the stream anew (no loss before it)
    begins: np.ndarray  # bool[N]: a restart, or the first packet of the stream (no step before it)
    step_ticks: np.ndarray  # int64[N]: the sensor's step from the last kept packet (0 where not kept or it begins)
    host_step_ns: np.ndarray  # int64[N]: capture time from the last kept packet (0 where unknown)
    host_known: np.ndarray  # bool[N]: both capture times known

    @property
    def corrupted(self) -> int:
        return int(np.count_nonzero(~self.keep))

    @property
    def restarts(self) -> int:
        return int(np.count_nonzero(self.restart))


class StreamContinuity:
    """The continuity of one stream, batch after batch (see the module docstring).

    Args:
        tick_ns: the duration of one tick of the packets' place (1000 for µs stamps; an Ouster
            packet period for its packet places).
        modulus: the place wraps at this many ticks (steps are taken within half of it), or ``None``.
    """

    def __init__(self, tick_ns: float, modulus: int | None = None) -> None:
        self.tick_ns = float(tick_ns)
        self.modulus = modulus
        self.corrupted = 0
        self.restarts = 0
        self._last: tuple[int, int] | None = None  # (place, host ns) of the last kept packet
        self._pending: tuple[int, int] | None = None  # a batch's last packet, skipped for want of a next one
        self._credit = 0.0  # packet periods of capture time not yet used by packets or losses

    def reset(self) -> None:
        """Forget the stream (a new stream, or a new mode whose places are not comparable)."""
        self._last = self._pending = None
        self._credit = 0.0

    def _step(self, place_to, place_from):
        d = np.asarray(place_to, np.int64) - np.asarray(place_from, np.int64)
        if self.modulus:
            half = self.modulus // 2
            d = (d + half) % self.modulus - half
        return d

    def _jump(self, a: tuple[int, int], b: tuple[int, int]) -> bool:
        known = bool(a[1] and b[1])
        return bool(jumps(np.array([self._step(b[0], a[0]) * self.tick_ns]), np.array([b[1] - a[1]]),
                          np.array([known]))[0])

    def check(self, place: np.ndarray, host_ns: np.ndarray) -> Steps:
        """Judge a batch of packets in arrival order: ``place`` (``int64[N]`` ticks), ``host_ns``
        (``int64[N]`` capture times, 0 where unknown). One NumPy pass; a short loop over the jumps only."""
        place = np.asarray(place, np.int64)
        host = np.asarray(host_ns, np.int64)
        n = len(place)
        keep, restart = np.ones(n, bool), np.zeros(n, bool)
        if n == 0:
            z = np.zeros(0, np.int64)
            return Steps(keep, restart, restart, z, z, np.zeros(0, bool))
        fresh = self._last is None and self._pending is None
        first = self._last if self._last is not None else (int(place[0]), int(host[0]))
        prev_place = np.concatenate([[first[0]], place[:-1]])
        prev_host = np.concatenate([[first[1]], host[:-1]])
        step = self._step(place, prev_place)
        known = (host != 0) & (prev_host != 0)
        jump = jumps(step * self.tick_ns, host - prev_host, known)
        if self._last is None:
            jump[0] = False
        if jump.any() or self._pending is not None:
            self._resolve(place, host, jump, keep, restart)
        if not keep.all():  # steps from the last kept packet
            kept = np.flatnonzero(keep)
            src = np.maximum.accumulate(np.where(keep, np.arange(n), -1))
            prev_kept = np.concatenate([[-1], src[:-1]])
            from_state = prev_kept < 0
            pp = np.where(from_state, first[0], place[np.maximum(prev_kept, 0)])
            ph = np.where(from_state, first[1], host[np.maximum(prev_kept, 0)])
            step = self._step(place, pp)
            known = (host != 0) & (ph != 0)
            prev_host = ph
            if kept.size:
                self._last = (int(place[kept[-1]]), int(host[kept[-1]]))
        else:
            self._last = (int(place[-1]), int(host[-1]))
        begins = restart.copy()
        if fresh:
            begins[np.argmax(keep)] = True
        counted = keep & ~begins
        step = np.where(counted, step, 0)
        host_step = np.where(known & counted, host - prev_host, 0)
        self.corrupted += int(np.count_nonzero(~keep))
        self.restarts += int(np.count_nonzero(restart))
        return Steps(keep, restart, begins, step, host_step, known & counted)

    def _resolve(self, place, host, jump, keep, restart) -> None:
        """Decide each jump: a corrupted packet (skipped) or a restart. Loops over the jumps only."""
        n = len(place)
        pending, self._pending = self._pending, None
        last = self._last

        def at(i):
            return (int(place[i]), int(host[i]))

        def ref(i):  # the last kept packet before i
            j = i - 1
            while j >= 0 and not keep[j]:
                j -= 1
            return at(j) if j >= 0 else last

        start = 0 if last is None and pending is None else None  # the stream begins in this batch, here
        todo = sorted(set(np.flatnonzero(jump).tolist()) | ({0} if pending is not None else set()))
        while todo:
            i = todo.pop(0)
            r = ref(i)
            if r is not None and not self._jump(r, at(i)):
                continue  # back on the timeline of the last kept packet
            if i == 0 and pending is not None and not self._jump(pending, at(0)):
                restart[0] = True  # the skipped last packet of the previous batch was a restart's first
                continue
            if r is None:
                continue
            if i + 1 < n:
                if self._jump(at(i), at(i + 1)):
                    keep[i] = False  # off both neighbours: corrupted
                    if i + 1 not in todo:
                        todo.insert(0, i + 1)
                elif start is not None and i == start + 1 and keep[start]:
                    keep[start] = False  # the stream's first packet was off the rest: corrupted
                else:
                    restart[i] = True  # the packets after it agree with it: the stream restarted
            else:
                keep[i] = False  # no packet after it yet: skipped; the next batch tells a restart
                self._pending = at(i)

    def bound_lost(self, lost: np.ndarray, host_step_ns: np.ndarray, host_known: np.ndarray,
                   period_ns: np.ndarray | float) -> np.ndarray:
        """``int64[N]``: the losses the sensor's steps claim (``lost``, per packet, in arrival order),
        each cut to the capture-time credit (see the module docstring); ``host_step_ns``: the capture
        time from the packet before (judged where ``host_known``; :class:`Steps` has both);
        ``period_ns``: the packet period, scalar or per packet. Where capture times are unknown the
        claim stands (its step is within :data:`INTERRUPTION_S` already)."""
        lost = np.asarray(lost, np.int64).copy()
        period = np.broadcast_to(np.asarray(period_ns, np.float64), lost.shape)
        gain = np.where(host_known, host_step_ns / period - 1.0, 0.0)
        cap = np.broadcast_to(INTERRUPTION_S * 1e9 / period, lost.shape)
        borrow = np.broadcast_to(CAPTURE_RESOLUTION_S * 1e9 / period, lost.shape)
        gaps = np.flatnonzero(lost > 0)
        cum = np.cumsum(gain)
        credit, base = self._credit, 0.0
        for i in gaps.tolist():  # gaps only: rare
            if not host_known[i]:
                continue
            credit = min(max(credit + cum[i] - base, -cap[i]), cap[i])
            base = cum[i]
            granted = min(int(lost[i]), max(int(np.rint(credit + borrow[i])), 0))
            lost[i] = granted
            credit -= granted
        if len(lost):
            credit = min(max(credit + cum[-1] - base, -cap[-1]), cap[-1])
        self._credit = credit
        return lost
