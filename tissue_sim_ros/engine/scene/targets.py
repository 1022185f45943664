"""Named points carried by the tissue: a tumour a planner aims at, a fiducial.

A target is given at rest (``targets: [{name, position_m}]`` in a scene) and embedded in the
element that contains it by its barycentric weights, so it moves with the deformation exactly as
the finite-element field does: x(t) = sum_k w_k (X_k + u_k(t)) over the element's four nodes (an
affine displacement field moves it exactly). What a planner asks of it: where it is now, how far
the needle tip is from it, and how far the needle's line passes beside it (the lateral miss).
"""
import numpy as np

from tissue_sim_ros.errors import SceneError

from tissue_sim_ros.engine.needle.kernels import locate_point

__all__ = ['Targets', 'check_targets']


def check_targets(entries, name='targets'):
    """The scene's ``targets`` list: each with a name and a position, names unique. Raises a
    ValueError naming the entry."""
    seen = set()
    for i, entry in enumerate(entries):
        if not entry.get('name'):
            raise SceneError(f'{name}[{i}].name = {entry.get("name")!r}: expected a non-empty name')
        if entry.get('position_m') is None:
            raise SceneError(f'{name}[{i}].position_m: required, the rest position [x, y, z] in metres')
        if entry['name'] in seen:
            raise SceneError(f'{name}[{i}].name = {entry["name"]!r}: another target has this name')
        seen.add(entry['name'])


class Targets:
    """The targets of a mesh: ``names`` (k,), ``rest`` (k, 3), ``elements`` (k,), ``weights`` (k, 4).

    ``entries``: the scene's ``targets`` (checked by :func:`check_targets`); a position outside
    the mesh is refused naming its entry.
    """

    def __init__(self, rest_positions, tetrahedra, entries, name='targets'):
        k = len(entries)
        self.names = [e['name'] for e in entries]
        self.rest = np.array([e['position_m'] for e in entries], dtype=float).reshape(k, 3)
        self.elements = np.zeros(k, dtype=np.int64)
        self.weights = np.zeros((k, 4))
        self._nodes = np.zeros((k, 4), dtype=np.int64)
        zero = np.zeros_like(rest_positions)
        tetrahedra = np.ascontiguousarray(tetrahedra, dtype=np.int64)     # the needle's kernels' types
        tolerance = 1e-9 * float(np.ptp(rest_positions, axis=0).max())
        for i in range(k):
            element, weights = locate_point(rest_positions, zero, tetrahedra, self.rest[i], tolerance)
            if element < 0:
                raise SceneError(f'{name}[{i}].position_m = {self.rest[i].tolist()}: outside the tissue mesh; '
                                 'a target must lie inside it')
            self.elements[i] = element
            self.weights[i] = weights
            self._nodes[i] = tetrahedra[element]

    def __len__(self):
        return len(self.names)

    def positions(self, displacement, out=None):
        """(k, 3) positions [m] now: the rest position plus the interpolated displacement."""
        if out is None:
            out = np.empty((len(self), 3))
        np.einsum('kn,knr->kr', self.weights, displacement[self._nodes], out=out)
        out += self.rest
        return out

    def relative_to_needle(self, positions, tip, axis):
        """(tip distance (k,), lateral miss (k,), ahead (k,)) [m]: the distance from the needle tip
        to each target, the target's distance from the needle's line, and how far along the axis
        it lies ahead of the tip (negative: behind it)."""
        offset = positions - tip
        ahead = offset @ axis
        lateral = offset - ahead[:, None] * axis
        return np.linalg.norm(offset, axis=1), np.linalg.norm(lateral, axis=1), ahead
