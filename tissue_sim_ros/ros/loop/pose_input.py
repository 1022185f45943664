"""The node's needle-pose input: validation, bad-input accounting and the pose at tick time.

Pure numpy, no rclpy: the node hands every received pose to :meth:`PoseInput.offer` and asks
:meth:`PoseInput.pose_at` for the pose at each tick. What happens to each kind of bad input
(the names are the diagnostics keys, ``bad_input.<kind>``):

==================== ===================================================================
kind                 handling
==================== ===================================================================
non_finite           NaN or inf in position or orientation: ignored
non_unit_quaternion  quaternion norm off 1 by more than ``unit_quaternion_tolerance``:
                     ignored (closer than that: normalised and accepted)
wrong_frame          ``header.frame_id`` is not ``expected_frame_id`` nor a frame on TF: ignored
                     (the node brings a pose in a frame on TF into the tissue frame first)
tf_unavailable       (the node) a pose in a frame on TF that TF cannot relate to the tissue
                     frame at its stamp, or, with ``input.source: tf``, a TF chain that cannot
                     be looked up: ignored
time_backwards       stamp older than the newest accepted pose's stamp: ignored
future_stamp         stamp more than ``max_future_s`` ahead of the node's clock (a clock
                     mismatch, e.g. use_sim_time on one side only): ignored
jump                 more than ``max_jump_m`` (or ``max_jump_rad``) from the newest accepted
                     pose, or from the needle when none is buffered: ignored (but see
                     resynchronised)
resynchronised       a jump received while the input is stale (the newest accepted pose
                     was received more than ``stale_after_s`` ago: a gap in the stream, or
                     nothing but refused poses since): accepted as the start of a new
                     stream, which the needle then joins gradually (below)
flood                stamp less than 1/``max_rate_hz`` after the stamp with which the newest
                     buffered sample was added: accepted, but it replaces that sample
                     instead of adding one (so a 1 kHz stream with max_rate_hz 250 adds
                     one sample per 4 ms, the latest pose always kept, and counts 3 of
                     every 4 poses as flood)
unstamped            stamp 0: accepted, stamped with its receipt time
malformed            (the node) a payload that does not decode as a PoseStamped: skipped
backlog              (the node) more poses waiting at one slice than it decodes: the oldest
                     are skipped, the newest kept (:mod:`~tissue_sim_ros.ros.loop.pose_receiver`)
engine_refused       (the node) a pose the engine refuses: the needle is held for that advance
==================== ===================================================================

Re-synchronisation. Without it, a robot that moved more than the jump limit while its stream
paused would be refused for ever (it does not come back). A jump from a stale stream therefore
restarts the buffer at the new pose, and :meth:`PoseInput.pose_at` hands out a pose that moves
from the last pose it handed out toward the new stream's pose at most ``resync_speed_m_s`` and
``resync_speed_rad_s`` (over at most RESYNC_STEP_MAX_S per call, so a call after a long pause
moves no farther), until it has reached the stream; from then on it follows the stream. With
the defaults a call moves the base at most 1 mm and turns the needle at most 0.0125 rad, so the
tip of a 0.15 m needle moves at most 2.9 mm: inside the engine's default jump limit (5 mm) for
one advance. A single wild pose in a
live stream is still refused as a jump; after a start or a reset, with no pose accepted yet,
a jump from the needle is refused whatever the wait (the needle's pose is the reference the
``~/reset`` service promises).

Delivery stalls. A pose received more than ``stale_after_s`` after its stamp, when the one
before came on time, starts a *delivery stall*: the stream was held up on the way and arrives as
a late burst (the publisher did not pause: it stamped these poses on time). Fast DDS does this
to a reliable subscription for about a second after an empty (0-byte) payload on its topic; a
best-effort subscription (``input.reliability: best_effort``) is not held up. Stalls are counted
(``delivery_stalls``, ``delivery_stall_max_s``) and diagnostics warn of them; the late poses are
judged as any others.

The pose at tick time ``t`` is interpolated (linear position, slerp orientation) between the
accepted samples whose stamps bracket ``t``; after the newest sample it is held (no
extrapolation); before the oldest it is the oldest. With nothing buffered, :meth:`pose_at`
returns None and the node holds the needle where it is. A pose is *stale* when the newest
accepted one was received more than ``stale_after_s`` ago: it is still held, and diagnostics
say so.
"""
from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np

from tissue_sim_ros.engine.needle.pose import (DEFAULT_MAX_JUMP_M, DEFAULT_MAX_JUMP_RAD, QUATERNION_NORM_TOLERANCE,
                                        pose_jump, rotation_angle, slerp, unit_quaternion)
from tissue_sim_ros.units import NS_PER_S

__all__ = ['ACCEPTED_KINDS', 'BAD_INPUT_KINDS', 'RESYNC_STEP_MAX_S', 'PoseInput', 'PoseInputLimits',
           'rotation_angle', 'slerp']

#: Every kind of bad input the node counts, in the order diagnostics list them. The last one is
#: counted by the node (the engine refused a pose that passed these checks, e.g. a needle that
#: would start inside the tissue, or a move beyond the scene's max jump within one tick).
BAD_INPUT_KINDS = ('non_finite', 'non_unit_quaternion', 'wrong_frame', 'tf_unavailable', 'time_backwards',
                   'future_stamp', 'jump', 'flood', 'unstamped', 'resynchronised', 'engine_refused',
                   'malformed', 'backlog')
#: The kinds :meth:`PoseInput.offer` reports for a pose it stored (not in ``bad_total``).
ACCEPTED_KINDS = ('flood', 'unstamped', 'resynchronised')
#: A catch-up step after a re-synchronisation covers at most this much time [s], however long
#: since the previous :meth:`PoseInput.pose_at` call (a pause, a held node).
RESYNC_STEP_MAX_S = 0.05


@dataclass(frozen=True)
class PoseInputLimits:
    """Thresholds of :class:`PoseInput` (the node's ``input.*`` parameters)."""

    expected_frame_id: str = 'world'
    max_jump_m: float = DEFAULT_MAX_JUMP_M
    max_jump_rad: float = DEFAULT_MAX_JUMP_RAD
    stale_after_s: float = 0.5
    max_future_s: float = 0.5
    max_rate_hz: float = 250.0
    unit_quaternion_tolerance: float = QUATERNION_NORM_TOLERANCE
    buffer_length: int = 64
    #: after a re-synchronisation, the handed-out pose joins the new stream at most this fast
    resync_speed_m_s: float = 0.02
    resync_speed_rad_s: float = 0.25


class PoseInput:
    """Accepted poses by stamp, counts of refused ones; see the module docstring."""

    def __init__(self, limits: PoseInputLimits, reference_pose=None):
        self.limits = limits
        self.counts = {kind: 0 for kind in BAD_INPUT_KINDS}
        self.received = 0
        self.accepted = 0
        self._samples: deque = deque(maxlen=int(limits.buffer_length))  # (stamp_ns, p, q)
        self._min_interval_ns = int(round(NS_PER_S / float(limits.max_rate_hz)))
        self._last_receipt_ns: int | None = None
        self._slot_start_ns = 0
        self._reference = None
        self._handed = None  # (t_ns, p, q) of the last pose pose_at handed out
        self._catching_up = False
        self.delivery_stalls = 0           # late bursts after on-time poses (module docstring)
        self.delivery_stall_max_s = 0.0    # the latest pose of any of them, after its stamp [s]
        self.last_stall_ns: int | None = None    # receipt time of the last stall's first pose
        self._on_time = True
        #: (stamp ns, position, orientation) of the newest pose that passed the value, frame and
        #: stamp checks, stored or not (a jump too): where the robot is (a needle registration)
        self.seen = None
        self.reset(reference_pose)

    def reset(self, reference_pose=None) -> None:
        """Forget the buffered poses; jumps are then measured from ``reference_pose``.

        ``reference_pose`` is (position, orientation xyzw) of the needle (None: no check until
        the first accepted pose). Counts are kept.
        """
        self._samples.clear()
        self._last_receipt_ns = None
        self._handed = None
        self._catching_up = False
        if reference_pose is None:
            self._reference = None
        else:
            p, q = reference_pose
            self._reference = (np.array(p, dtype=np.float64), np.array(q, dtype=np.float64))

    # -- in ---------------------------------------------------------------------------------

    def offer(self, position, orientation, frame_id: str, stamp_ns: int, receipt_ns: int):
        """Judge one received pose. Returns (kind or None, detail): None when it was stored.

        ``kind`` is one of BAD_INPUT_KINDS; poses of the ACCEPTED_KINDS ('flood', 'unstamped',
        'resynchronised') are stored too (the caller may log them). ``detail`` says what was wrong, with the values.
        """
        self.received += 1
        if stamp_ns != 0:
            self._watch_delivery(stamp_ns, receipt_ns)
        lim = self.limits
        p = np.asarray(position, dtype=np.float64)
        q = np.asarray(orientation, dtype=np.float64)
        if not (np.isfinite(p).all() and np.isfinite(q).all()):
            return self._bad('non_finite', f'position {p.tolist()} orientation {q.tolist()}')
        unit, norm = unit_quaternion(q, lim.unit_quaternion_tolerance)
        if unit is None:
            return self._bad('non_unit_quaternion',
                             f'quaternion {q.tolist()} has norm {norm:.6g}; expected 1 within '
                             f'{lim.unit_quaternion_tolerance}')
        if frame_id != lim.expected_frame_id:
            return self._bad('wrong_frame',
                             f'frame_id {frame_id!r}; expected {lim.expected_frame_id!r} or a frame on TF')
        note = None
        if stamp_ns == 0:
            stamp_ns = receipt_ns
            note = 'unstamped'
        if stamp_ns > receipt_ns + lim.max_future_s * NS_PER_S:
            return self._bad('future_stamp',
                             f'stamp {stamp_ns / NS_PER_S:.9f} s is '
                             f'{(stamp_ns - receipt_ns) / NS_PER_S:.3g} s ahead of the node clock '
                             f'(max {lim.max_future_s} s): use_sim_time set on one side only?')
        self.seen = (stamp_ns, p, unit)
        newest = self._samples[-1] if self._samples else None
        if newest is not None and stamp_ns < newest[0]:
            return self._bad('time_backwards',
                             f'stamp {stamp_ns / NS_PER_S:.9f} s is before the previous pose '
                             f'({newest[0] / NS_PER_S:.9f} s)')
        q = unit
        ref = (newest[1], newest[2]) if newest is not None else self._reference
        if ref is not None:
            jump = pose_jump(ref[0], ref[1], p, q)
            if jump.exceeds(lim.max_jump_m, lim.max_jump_rad):
                what = (f'{jump.distance_m * 1e3:.4g} mm and {jump.angle_rad:.4g} rad from the '
                        f'{"previous pose" if newest is not None else "needle"}; '
                        f'max {lim.max_jump_m * 1e3:.4g} mm, {lim.max_jump_rad:.4g} rad')
                if not self.stale(receipt_ns):
                    return self._bad('jump', what)
                if note is not None:
                    self.counts[note] += 1
                return self._resynchronise(p, q, stamp_ns, receipt_ns, what)
        if note is not None:
            self.counts[note] += 1
        if newest is not None and stamp_ns - self._slot_start_ns < self._min_interval_ns:
            self._samples[-1] = (stamp_ns, p, q)  # coalesce: keep the newest, not more samples
            self.counts['flood'] += 1
            note = note or 'flood'
        else:
            self._samples.append((stamp_ns, p, q))
            self._slot_start_ns = stamp_ns
        self.accepted += 1
        self._last_receipt_ns = receipt_ns
        detail = None
        if note == 'flood':
            detail = (f'poses {(stamp_ns - newest[0]) / 1e6:.3g} ms apart, closer than '
                      f'1/input.max_rate_hz = {self._min_interval_ns / 1e6:.3g} ms: coalesced')
        elif note == 'unstamped':
            detail = 'header.stamp is 0; stamped with the receipt time'
        return note, detail

    def _watch_delivery(self, stamp_ns: int, receipt_ns: int) -> None:
        """Count a delivery stall: a pose late by more than ``stale_after_s`` after one on time."""
        late_s = (receipt_ns - stamp_ns) / NS_PER_S
        late = late_s > self.limits.stale_after_s
        if late and self._on_time:
            self.delivery_stalls += 1
            self.last_stall_ns = receipt_ns
        if late:
            self.delivery_stall_max_s = max(self.delivery_stall_max_s, late_s)
        self._on_time = not late

    def _resynchronise(self, p, q, stamp_ns: int, receipt_ns: int, what: str):
        """Start a new stream at this pose; pose_at joins it gradually (module docstring)."""
        if self._handed is None:  # nothing handed out yet: start from the newest accepted pose
            newest = self._samples[-1]
            self._handed = (stamp_ns, newest[1], newest[2])
        self._samples.clear()
        self._samples.append((stamp_ns, p, q))
        self._slot_start_ns = stamp_ns
        self._catching_up = True
        self.counts['resynchronised'] += 1
        self.accepted += 1
        age = (receipt_ns - self._last_receipt_ns) / NS_PER_S
        self._last_receipt_ns = receipt_ns
        lim = self.limits
        return 'resynchronised', (f'{what}, but no pose accepted for {age:.3g} s (input.stale_after_s '
                                  f'= {lim.stale_after_s:g} s): a new stream, joined at '
                                  f'{lim.resync_speed_m_s * 1e3:.4g} mm/s and {lim.resync_speed_rad_s:.4g} rad/s')

    def _bad(self, kind: str, detail: str):
        self.counts[kind] += 1
        return kind, detail

    def count(self, kind: str) -> None:
        """Count a bad input found elsewhere (the node: 'engine_refused'; a kind of its own, e.g.
        a payload that does not decode, gets its key in ``counts`` at its first count)."""
        self.counts[kind] = self.counts.get(kind, 0) + 1

    # -- out --------------------------------------------------------------------------------

    def pose_at(self, t_ns: int):
        """(position (3,), orientation (4,)) at time ``t_ns``, or None if nothing is buffered.

        Samples older than the last one at or before ``t_ns`` are dropped (ticks move forward).
        """
        samples = self._samples
        if not samples:
            return None
        while len(samples) >= 2 and samples[1][0] <= t_ns:
            samples.popleft()
        s0 = samples[0]
        if t_ns <= s0[0] or len(samples) == 1:
            pose = s0[1], s0[2]
        else:
            s1 = samples[1]
            w = (t_ns - s0[0]) / (s1[0] - s0[0])
            pose = s0[1] + w * (s1[1] - s0[1]), slerp(s0[2], s1[2], w)
        if self._catching_up:
            pose = self._catch_up(t_ns, *pose)
        self._handed = (t_ns, pose[0], pose[1])
        return pose

    def _catch_up(self, t_ns: int, position, orientation):
        """The pose one step from the last handed-out pose toward the stream's (position,
        orientation): at most resync_speed * min(time since the last call, RESYNC_STEP_MAX_S);
        the stream's pose itself once it is within that step (the catch-up ends)."""
        t0, p0, q0 = self._handed
        dt = min(max(0, t_ns - t0) / NS_PER_S, RESYNC_STEP_MAX_S)
        step_m, step_rad = self.limits.resync_speed_m_s * dt, self.limits.resync_speed_rad_s * dt
        gap = pose_jump(p0, q0, position, orientation)
        if gap.distance_m <= step_m and gap.angle_rad <= step_rad:
            self._catching_up = False
            return position, orientation
        if gap.distance_m > step_m:
            position = p0 + (step_m / gap.distance_m) * (position - p0)
        if gap.angle_rad > step_rad:
            orientation = slerp(q0, orientation, step_rad / gap.angle_rad)
        return position, orientation

    @property
    def catching_up(self) -> bool:
        """True while pose_at is still joining a re-synchronised stream."""
        return self._catching_up

    def newest(self):
        """(stamp_ns, position, orientation) of the newest accepted pose, or None."""
        return self._samples[-1] if self._samples else None

    def oldest(self):
        """(stamp_ns, position, orientation) of the oldest buffered pose, or None."""
        return self._samples[0] if self._samples else None

    def age_s(self, now_ns: int) -> float | None:
        """Seconds since the newest accepted pose was received (None: none yet)."""
        if self._last_receipt_ns is None:
            return None
        return (now_ns - self._last_receipt_ns) / NS_PER_S

    def stale(self, now_ns: int) -> bool:
        age = self.age_s(now_ns)
        return age is not None and age > self.limits.stale_after_s

    @property
    def bad_total(self) -> int:
        return sum(v for k, v in self.counts.items() if k not in ACCEPTED_KINDS)
