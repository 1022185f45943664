"""Named points carried by the tissue: a tumour a planner aims at, a fiducial.

A target is given at rest (``targets: [{name, position_m}]`` in a scene, or ``{name, region}``:
the volume-weighted centroid of a region's elements, a tumour's centre) and embedded in the
element that contains it by its barycentric weights, so it moves with the deformation exactly as
the finite-element field does: x(t) = sum_k w_k (X_k + u_k(t)) over the element's four nodes (an
affine displacement field moves it exactly). What a planner asks of it: where it is now, how far
the needle tip is from it, and how far the needle's line passes beside it (the lateral miss).
"""
import numpy as np

from tissue_sim_ros.errors import SceneError

from tissue_sim_ros.engine.needle.kernels import locate_point

__all__ = ['Targets', 'check_targets', 'region_centroid']


def check_targets(entries, name='targets'):
    """The scene's ``targets`` list: each with a name and a position, names unique. Raises a
    ValueError naming the entry."""
    seen = set()
    for i, entry in enumerate(entries):
        if not entry.get('name'):
            raise SceneError(f'{name}[{i}].name = {entry.get("name")!r}: expected a non-empty name')
        if (entry.get('position_m') is None) == (entry.get('region') is None):
            raise SceneError(f'{name}[{i}]: give one of position_m (the rest position [x, y, z] in metres) and '
                             "region (a region's name: its centroid)")
        if entry['name'] in seen:
            raise SceneError(f'{name}[{i}].name = {entry["name"]!r}: another target has this name')
        seen.add(entry['name'])


def region_centroid(rest_positions, tetrahedra, element_region, region_names, region, field):
    """The volume-weighted centroid [m] of the elements of the region named ``region``."""
    if region not in region_names:
        raise SceneError(f'{field} = {region!r}: no region of that name; the regions are {", ".join(region_names)}')
    elements = np.flatnonzero(np.asarray(element_region) == region_names.index(region))
    if len(elements) == 0:
        raise SceneError(f'{field} = {region!r}: the region holds no element of the mesh')
    corners = np.asarray(rest_positions)[np.asarray(tetrahedra)[elements]]
    volumes = np.abs(np.einsum('ij,ij->i', np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]),
                               corners[:, 3] - corners[:, 0]))
    return (corners.mean(axis=1) * volumes[:, None]).sum(axis=0) / volumes.sum()


class Targets:
    """The targets of a mesh: ``names`` (k,), ``rest`` (k, 3), ``elements`` (k,), ``weights`` (k, 4).

    ``entries``: the scene's ``targets`` (checked by :func:`check_targets`); a position outside
    the mesh is refused naming its entry. ``element_region`` (m,) and ``region_names``: where a
    target given by ``region`` is (:func:`region_centroid`).
    """

    def __init__(self, rest_positions, tetrahedra, entries, name='targets', element_region=None, region_names=()):
        k = len(entries)
        self.names = [e['name'] for e in entries]
        self.rest = np.array([e['position_m'] if e.get('position_m') is not None else
                              region_centroid(rest_positions, tetrahedra, element_region, list(region_names),
                                              e['region'], f'{name}[{i}].region')
                              for i, e in enumerate(entries)], dtype=float).reshape(k, 3)
        self.elements = np.zeros(k, dtype=np.int64)
        self.weights = np.zeros((k, 4))
        self._nodes = np.zeros((k, 4), dtype=np.int64)
        zero = np.zeros_like(rest_positions)
        tetrahedra = np.ascontiguousarray(tetrahedra, dtype=np.int64)     # the needle's kernels' types
        tolerance = 1e-9 * float(np.ptp(rest_positions, axis=0).max())
        for i in range(k):
            element, weights = locate_point(rest_positions, zero, tetrahedra, self.rest[i], tolerance)
            if element < 0:
                key = 'position_m' if entries[i].get('position_m') is not None else 'region'
                raise SceneError(f'{name}[{i}].{key} = {self.rest[i].tolist()}: outside the tissue mesh; '
                                 'a target must lie inside it (a curved region\'s centroid may not: give position_m)')
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
