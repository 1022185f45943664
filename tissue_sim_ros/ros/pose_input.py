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
wrong_frame          ``header.frame_id`` is not ``expected_frame_id`` (no tf here): ignored
time_backwards       stamp older than the newest accepted pose's stamp: ignored
future_stamp         stamp more than ``max_future_s`` ahead of the node's clock (a clock
                     mismatch, e.g. use_sim_time on one side only): ignored
jump                 more than ``max_jump_m`` (or ``max_jump_rad``) from the newest accepted
                     pose, or from the needle when none is buffered: ignored
flood                stamp less than 1/``max_rate_hz`` after the stamp with which the newest
                     buffered sample was added: accepted, but it replaces that sample
                     instead of adding one (so a 1 kHz stream with max_rate_hz 250 adds
                     one sample per 4 ms, the latest pose always kept, and counts 3 of
                     every 4 poses as flood)
unstamped            stamp 0: accepted, stamped with its receipt time
==================== ===================================================================

The pose at tick time ``t`` is interpolated (linear position, slerp orientation) between the
accepted samples whose stamps bracket ``t``; after the newest sample it is held (no
extrapolation); before the oldest it is the oldest. With nothing buffered, :meth:`pose_at`
returns None and the node holds the needle where it is. A pose is *stale* when the newest
accepted one was received more than ``stale_after_s`` ago: it is still held, and diagnostics
say so.
"""
from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from tissue_sim_ros.engine.needle import QUATERNION_NORM_TOLERANCE, slerp  # shared with the engine

__all__ = ['BAD_INPUT_KINDS', 'PoseInput', 'PoseInputLimits', 'slerp']

#: Every kind of bad input the node counts, in the order diagnostics list them. The last one is
#: counted by the node (the engine refused a pose that passed these checks, e.g. a needle that
#: would start inside the tissue, or a move beyond the scene's max jump within one tick).
BAD_INPUT_KINDS = ('non_finite', 'non_unit_quaternion', 'wrong_frame', 'time_backwards',
                   'future_stamp', 'jump', 'flood', 'unstamped', 'engine_refused')

_NS = 1_000_000_000


def rotation_angle(q0: np.ndarray, q1: np.ndarray) -> float:
    """Angle [rad] of the rotation between two unit quaternions."""
    return 2.0 * math.acos(min(1.0, abs(float(np.dot(q0, q1)))))


@dataclass(frozen=True)
class PoseInputLimits:
    """Thresholds of :class:`PoseInput` (the node's ``input.*`` parameters)."""

    expected_frame_id: str = 'world'
    max_jump_m: float = 0.005
    max_jump_rad: float = 0.5
    stale_after_s: float = 0.5
    max_future_s: float = 0.5
    max_rate_hz: float = 250.0
    unit_quaternion_tolerance: float = QUATERNION_NORM_TOLERANCE
    buffer_length: int = 64


class PoseInput:
    """Accepted poses by stamp, counts of refused ones; see the module docstring."""

    def __init__(self, limits: PoseInputLimits, reference_pose=None):
        self.limits = limits
        self.counts = {kind: 0 for kind in BAD_INPUT_KINDS}
        self.received = 0
        self.accepted = 0
        self._samples: deque = deque(maxlen=int(limits.buffer_length))  # (stamp_ns, p, q)
        self._min_interval_ns = int(round(_NS / float(limits.max_rate_hz)))
        self._last_receipt_ns: int | None = None
        self._slot_start_ns = 0
        self._reference = None
        self.reset(reference_pose)

    def reset(self, reference_pose=None) -> None:
        """Forget the buffered poses; jumps are then measured from ``reference_pose``.

        ``reference_pose`` is (position, orientation xyzw) of the needle (None: no check until
        the first accepted pose). Counts are kept.
        """
        self._samples.clear()
        self._last_receipt_ns = None
        if reference_pose is None:
            self._reference = None
        else:
            p, q = reference_pose
            self._reference = (np.array(p, dtype=np.float64), np.array(q, dtype=np.float64))

    # -- in ---------------------------------------------------------------------------------

    def offer(self, position, orientation, frame_id: str, stamp_ns: int, receipt_ns: int):
        """Judge one received pose. Returns (kind or None, detail): None when it was stored.

        ``kind`` is one of BAD_INPUT_KINDS; 'flood' and 'unstamped' poses are stored too (the
        caller may log them). ``detail`` says what was wrong, with the values.
        """
        self.received += 1
        lim = self.limits
        p = np.asarray(position, dtype=np.float64)
        q = np.asarray(orientation, dtype=np.float64)
        if not (np.isfinite(p).all() and np.isfinite(q).all()):
            return self._bad('non_finite', f'position {p.tolist()} orientation {q.tolist()}')
        norm = float(np.sqrt(q @ q))
        if abs(norm - 1.0) > lim.unit_quaternion_tolerance:
            return self._bad('non_unit_quaternion',
                             f'quaternion {q.tolist()} has norm {norm:.6g}; expected 1 within '
                             f'{lim.unit_quaternion_tolerance}')
        if frame_id != lim.expected_frame_id:
            return self._bad('wrong_frame',
                             f'frame_id {frame_id!r}; expected {lim.expected_frame_id!r}')
        note = None
        if stamp_ns == 0:
            stamp_ns = receipt_ns
            note = 'unstamped'
        if stamp_ns > receipt_ns + lim.max_future_s * _NS:
            return self._bad('future_stamp',
                             f'stamp {stamp_ns / _NS:.9f} s is {(stamp_ns - receipt_ns) / _NS:.3g} s '
                             f'ahead of the node clock (max {lim.max_future_s} s): use_sim_time '
                             'set on one side only?')
        newest = self._samples[-1] if self._samples else None
        if newest is not None and stamp_ns < newest[0]:
            return self._bad('time_backwards',
                             f'stamp {stamp_ns / _NS:.9f} s is before the previous pose '
                             f'({newest[0] / _NS:.9f} s)')
        q = q / norm
        ref = (newest[1], newest[2]) if newest is not None else self._reference
        if ref is not None:
            distance = float(np.linalg.norm(p - ref[0]))
            angle = rotation_angle(q, ref[1])
            if distance > lim.max_jump_m or angle > lim.max_jump_rad:
                return self._bad('jump',
                                 f'{distance * 1e3:.4g} mm and {angle:.4g} rad from the '
                                 f'{"previous pose" if newest is not None else "needle"}; '
                                 f'max {lim.max_jump_m * 1e3:.4g} mm, {lim.max_jump_rad:.4g} rad')
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

    def _bad(self, kind: str, detail: str):
        self.counts[kind] += 1
        return kind, detail

    def count(self, kind: str) -> None:
        """Count a bad input found elsewhere (the node: 'engine_refused')."""
        self.counts[kind] += 1

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
            return s0[1], s0[2]
        s1 = samples[1]
        w = (t_ns - s0[0]) / (s1[0] - s0[0])
        return s0[1] + w * (s1[1] - s0[1]), slerp(s0[2], s1[2], w)

    def newest(self):
        """(stamp_ns, position, orientation) of the newest accepted pose, or None."""
        return self._samples[-1] if self._samples else None

    def age_s(self, now_ns: int) -> float | None:
        """Seconds since the newest accepted pose was received (None: none yet)."""
        if self._last_receipt_ns is None:
            return None
        return (now_ns - self._last_receipt_ns) / _NS

    def stale(self, now_ns: int) -> bool:
        age = self.age_s(now_ns)
        return age is not None and age > self.limits.stale_after_s

    @property
    def bad_total(self) -> int:
        return sum(v for k, v in self.counts.items() if k not in ('flood', 'unstamped'))
