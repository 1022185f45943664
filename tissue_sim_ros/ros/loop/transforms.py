"""Rigid transforms and a TF buffer without rclpy: what tf2_ros's Buffer does for the node.

A transform is ``(translation (3,), rotation (4,) x y z w)``: the pose of a child frame in its parent,
so that a point ``p`` given in the child is ``R p + t`` in the parent (the layout of
geometry_msgs/TransformStamped, REP 103). :func:`compose` chains them (``compose(a_from_b,
b_from_c)`` is ``a_from_c``), :func:`invert` turns one round.

:class:`TransformBuffer` keeps, per child frame, its parent and the transforms received with their
stamps (the last ``cache_s`` seconds of them; a static one for ever), as /tf and /tf_static deliver
them. :meth:`TransformBuffer.lookup` relates any two frames of one tree: it walks from each up to
their common ancestor and composes the edges, each at the stamp asked for, interpolated between the
two samples that bracket it (linear translation, slerp rotation: tf2's rule). Stamp 0 asks for the
latest time every edge of the chain has (tf2's ``Time(0)``). A stamp before an edge's oldest sample or
after its newest raises :class:`TransformUnavailable` (no extrapolation), as does a frame no edge
names or two frames in different trees; the message names the frames and the stamps.

Thread-safe: the executor's thread adds transforms while the engine's thread looks them up.
"""

from __future__ import annotations

import bisect
import math
import threading

import numpy as np

from tissue_sim_ros.engine.needle.pose import rotation_matrix, slerp
from tissue_sim_ros.errors import InputError
from tissue_sim_ros.units import NS_PER_S

__all__ = [
    'IDENTITY',
    'TransformBuffer',
    'TransformUnavailable',
    'compose',
    'invert',
    'quaternion_product',
    'transform_point',
]

#: the transform that changes nothing
IDENTITY = (np.zeros(3), np.array([0.0, 0.0, 0.0, 1.0]))


class TransformUnavailable(InputError):
    """A lookup the buffer cannot answer: a frame it does not know, frames in different trees, or a
    stamp outside what it holds for an edge."""


def _product(a, b) -> tuple[float, float, float, float]:
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return (
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
        aw * bw - ax * bx - ay * by - az * bz,
    )


def _rotate(q, v) -> tuple[float, float, float]:
    """``v`` rotated by the unit quaternion ``q``: v + w t + q_xyz x t with t = 2 q_xyz x v (the
    same rotation as :func:`~tissue_sim_ros.engine.needle.pose.rotation_matrix`, in floats: a TF
    message is a few of these, at the robot's rate, on the executor's thread)."""
    x, y, z, w = q
    vx, vy, vz = v
    tx, ty, tz = 2.0 * (y * vz - z * vy), 2.0 * (z * vx - x * vz), 2.0 * (x * vy - y * vx)
    return vx + w * tx + (y * tz - z * ty), vy + w * ty + (z * tx - x * tz), vz + w * tz + (x * ty - y * tx)


def quaternion_product(a, b) -> np.ndarray:
    """The Hamilton product ``a b`` of quaternions x y z w: the rotation b, then a."""
    return np.array(_product(a, b))


def transform_point(transform, point) -> np.ndarray:
    """``point`` (3,) given in the child frame, in the parent frame."""
    translation, rotation = transform
    return rotation_matrix(rotation) @ np.asarray(point, dtype=np.float64) + translation


def _floats(values) -> list[float]:
    return values.tolist() if isinstance(values, np.ndarray) else [float(v) for v in values]


def compose(a_from_b, b_from_c):
    """``a_from_c``: the transform of frame c into frame a through b."""
    t_ab, q_ab = (_floats(v) for v in a_from_b)
    t_bc, q_bc = (_floats(v) for v in b_from_c)
    q = _product(q_ab, q_bc)
    norm = math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    r = _rotate(q_ab, t_bc)
    return (
        np.array([r[0] + t_ab[0], r[1] + t_ab[1], r[2] + t_ab[2]]),
        np.array([q[0] / norm, q[1] / norm, q[2] / norm, q[3] / norm]),
    )


def invert(a_from_b):
    """``b_from_a``."""
    t, q = (_floats(v) for v in a_from_b)
    conjugate = (-q[0], -q[1], -q[2], q[3])
    r = _rotate(conjugate, t)
    return np.array([-r[0], -r[1], -r[2]]), np.array(conjugate)


class _Edge:
    """One child frame's transforms to its parent, by stamp."""

    __slots__ = ('parent', 'static', 'stamps', 'values')

    def __init__(self, parent: str, static: bool):
        self.parent, self.static = parent, static
        self.stamps: list[int] = []
        self.values: list[tuple] = []

    def add(self, stamp_ns: int, translation, rotation, cache_ns: int) -> None:
        value = (np.array(translation, dtype=np.float64), np.array(rotation, dtype=np.float64))
        if self.static:
            self.stamps, self.values = [stamp_ns], [value]
            return
        if self.stamps and stamp_ns <= self.stamps[-1]:
            k = bisect.bisect_left(self.stamps, stamp_ns)
            if k < len(self.stamps) and self.stamps[k] == stamp_ns:
                self.values[k] = value  # the same stamp again: the newer wins
                return
            self.stamps.insert(k, stamp_ns)
            self.values.insert(k, value)
        else:
            self.stamps.append(stamp_ns)
            self.values.append(value)
        cut = bisect.bisect_left(self.stamps, self.stamps[-1] - cache_ns)
        if cut > 256:  # trimmed in batches, not at every add
            del self.stamps[:cut], self.values[:cut]

    def at(self, stamp_ns: int, child: str):
        if self.static:
            return self.values[0]
        stamps = self.stamps
        if not stamps or stamp_ns < stamps[0] or stamp_ns > stamps[-1]:
            held = 'nothing' if not stamps else f'{stamps[0] / NS_PER_S:.9f} .. {stamps[-1] / NS_PER_S:.9f} s'
            raise TransformUnavailable(
                f'transform {self.parent} <- {child} at {stamp_ns / NS_PER_S:.9f} s: '
                f'the buffer holds {held} (no extrapolation)'
            )
        k = bisect.bisect_left(stamps, stamp_ns)
        if stamps[k] == stamp_ns:
            return self.values[k]
        (t0, q0), (t1, q1) = self.values[k - 1], self.values[k]
        w = (stamp_ns - stamps[k - 1]) / (stamps[k] - stamps[k - 1])
        return t0 + w * (t1 - t0), slerp(q0, q1, w)

    @property
    def newest_ns(self) -> int | None:
        return None if self.static or not self.stamps else self.stamps[-1]


class TransformBuffer:
    """Transforms by child frame (see the module docstring); ``cache_s``: how much history each
    dynamic edge keeps."""

    def __init__(self, cache_s: float = 10.0):
        self.cache_ns = int(cache_s * NS_PER_S)
        self._edges: dict[str, _Edge] = {}
        self._lock = threading.Lock()
        self.received = 0

    def set_transform(
        self, parent: str, child: str, stamp_ns: int, translation, rotation, static: bool = False
    ) -> None:
        """Add one transform (the pose of ``child`` in ``parent`` at ``stamp_ns``). A child that
        changes parent starts afresh, as tf2 does."""
        if not parent or not child or parent == child:
            raise TransformUnavailable(
                f'transform {parent!r} <- {child!r}: two different non-empty frames ' 'expected'
            )
        with self._lock:
            edge = self._edges.get(child)
            if edge is None or edge.parent != parent or edge.static != static:
                edge = self._edges[child] = _Edge(parent, static)
            edge.add(int(stamp_ns), translation, rotation, self.cache_ns)
            self.received += 1

    def frames(self) -> set[str]:
        """Every frame an edge names."""
        with self._lock:
            return set(self._edges) | {e.parent for e in self._edges.values()}

    def parent(self, frame: str) -> str | None:
        with self._lock:
            edge = self._edges.get(frame)
            return None if edge is None else edge.parent

    def _path_to_root(self, frame: str) -> list[str]:
        path, seen = [frame], {frame}
        while path[-1] in self._edges:
            parent = self._edges[path[-1]].parent
            if parent in seen:
                raise TransformUnavailable(f'frames {path + [parent]} form a loop')
            path.append(parent)
            seen.add(parent)
        return path

    def chain(self, target: str, source: str) -> tuple[list[str], list[str]]:
        """(frames from ``source`` up to the common ancestor, frames from ``target`` up to it),
        each starting with its own frame and ending with the ancestor."""
        with self._lock:
            return self._chain(target, source)

    def _chain(self, target, source):
        known = set(self._edges) | {e.parent for e in self._edges.values()}
        for frame in (target, source):
            if frame not in known:
                raise TransformUnavailable(f'frame {frame!r} is not on TF (known: {sorted(known)[:12]})')
        up_source, up_target = self._path_to_root(source), self._path_to_root(target)
        common = next((f for f in up_source if f in set(up_target)), None)
        if common is None:
            raise TransformUnavailable(
                f'frames {target!r} and {source!r} are in different trees (roots '
                f'{up_target[-1]!r} and {up_source[-1]!r})'
            )
        return up_source[: up_source.index(common) + 1], up_target[: up_target.index(common) + 1]

    def lookup(self, target: str, source: str, stamp_ns: int = 0):
        """(transform ``target_from_source``, the stamp used [ns]): a pose in ``source`` composed with
        it is that pose in ``target``. ``stamp_ns`` 0: the latest time the whole chain has (0 when
        every edge is static)."""
        if target == source:
            return IDENTITY, int(stamp_ns)
        with self._lock:
            up_source, up_target = self._chain(target, source)
            edges = [(f, self._edges[f]) for f in up_source[:-1]] + [
                (f, self._edges[f]) for f in up_target[:-1]
            ]
            if stamp_ns == 0:
                newest = [e.newest_ns for _, e in edges if not e.static]
                if any(n is None for n in newest):
                    raise TransformUnavailable(
                        f'transform {target} <- {source}: an edge has no transform yet'
                    )
                stamp_ns = min(newest) if newest else 0
            ancestor_from_source = IDENTITY
            for frame in reversed(up_source[:-1]):  # from the ancestor down to the source
                ancestor_from_source = compose(ancestor_from_source, self._edges[frame].at(stamp_ns, frame))
            ancestor_from_target = IDENTITY
            for frame in reversed(up_target[:-1]):
                ancestor_from_target = compose(ancestor_from_target, self._edges[frame].at(stamp_ns, frame))
        return compose(invert(ancestor_from_target), ancestor_from_source), int(stamp_ns)

    def newest_ns(self, frames) -> int | None:
        """The newest stamp of any dynamic edge among ``frames`` (child frames), or None."""
        with self._lock:
            stamps = [e.newest_ns for f in frames if (e := self._edges.get(f)) is not None and not e.static]
        stamps = [s for s in stamps if s is not None]
        return max(stamps) if stamps else None
