"""Per-element data of a tetrahedral mesh: its rest geometry and which material each element has.

What :class:`~tissue_sim_ros.engine.model.tensor_mass.TensorMassModel` precomputes once per
element: the shape-function gradients, the rest volume and the edge Gram sums the mean ratio
needs (docs/method.md, "Shape-function gradients", "Liu-Joe mean ratio").
"""
import numpy as np

from tissue_sim_ros.engine.model.material import Material
from tissue_sim_ros.errors import MaterialError

__all__ = ['LOCAL_EDGES', 'element_geometry', 'per_element_material']

#: the six edges of a tetrahedron as pairs of local vertex numbers
LOCAL_EDGES = ((0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3))


def element_geometry(rest_positions, tetrahedra):
    """Shape-function gradients (m, 3, 3) (rows a_1..a_3), rest volumes (m,), edge Gram (m, 6).

    With D = [P1 - P0, P2 - P0, P3 - P0] (columns), the rows of D^-1 are a_1, a_2, a_3 and
    V = det(D) / 6 (docs/method.md, "Shape-function gradients").
    """
    corners = rest_positions[tetrahedra]                        # (m, 4, 3)
    columns = (corners[:, 1:, :] - corners[:, :1, :]).transpose(0, 2, 1)
    volumes = np.linalg.det(columns) / 6.0
    shape_gradients = np.ascontiguousarray(np.linalg.inv(columns))
    gram = np.zeros((len(tetrahedra), 6))
    for j, k in LOCAL_EDGES:
        edge = corners[:, k, :] - corners[:, j, :]
        gram[:, 0] += edge[:, 0] ** 2
        gram[:, 1] += edge[:, 1] ** 2
        gram[:, 2] += edge[:, 2] ** 2
        gram[:, 3] += edge[:, 0] * edge[:, 1]
        gram[:, 4] += edge[:, 0] * edge[:, 2]
        gram[:, 5] += edge[:, 1] * edge[:, 2]
    return shape_gradients, volumes, gram


def per_element_material(mesh, material):
    """Material of each element: one Material, or a {region tag: Material} mapping."""
    if isinstance(material, Material):
        return [material], np.zeros(mesh.n_elements, dtype=np.int64)
    if isinstance(material, dict) and all(isinstance(m, Material) for m in material.values()):
        tags = np.unique(mesh.element_tags)
        missing = sorted(set(tags.tolist()) - set(material))
        if missing:
            raise MaterialError(f'material: no Material for element tag(s) {missing}; '
                                f'expected a key for every tag in the mesh {tags.tolist()}')
        keys = sorted(material)
        index_of = {k: i for i, k in enumerate(keys)}
        return [material[k] for k in keys], np.array([index_of[t] for t in mesh.element_tags.tolist()])
    raise MaterialError(f'material = {material!r}: expected a Material or a dict of tag -> Material')
