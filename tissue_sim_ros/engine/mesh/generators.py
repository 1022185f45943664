"""Mesh generators: boxes of Kuhn-split hexahedra, uniform (box_mesh) or graded toward a
needle's entry point (graded_box_mesh). Elements come hexahedron by hexahedron, x fastest, so
memory order follows space (the element pass's chunks stay local)."""
import math

import numpy as np

from tissue_sim_ros.engine.mesh.tetmesh import TetMesh, make_mesh
from tissue_sim_ros.errors import MeshError

__all__ = ['box_axes', 'box_mesh', 'graded_box_axes', 'graded_box_mesh', 'grid_elements', 'grid_mesh']


def _as_float_triple(value, field: str, *, positive: bool) -> np.ndarray:
    try:
        triple = np.array(value, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError) as exc:
        raise MeshError(f'{field}: {value!r} is not numeric; expected 3 numbers') from exc
    if triple.shape != (3,):
        raise MeshError(f'{field}: {value!r} has {triple.size} values, expected 3')
    if not np.isfinite(triple).all():
        raise MeshError(f'{field}: {value!r} is not finite, expected finite numbers')
    if positive and (triple <= 0).any():
        raise MeshError(f'{field}: {value!r}, expected 3 positive lengths in metres')
    return triple


def _as_divisions(value, field: str = 'divisions') -> tuple[int, int, int]:
    raw = np.asarray(value)
    if raw.shape != (3,) or raw.dtype.kind not in 'iu' or (raw < 1).any():
        raise MeshError(f'{field}: {value!r}, expected 3 integers >= 1 (cells along x, y, z)')
    return int(raw[0]), int(raw[1]), int(raw[2])


def _as_positive_scalar(value, field: str, *, allow_zero: bool = False,
                        minimum: float | None = None) -> float:
    try:
        number = float(value)
    except (TypeError, ValueError) as exc:
        raise MeshError(f'{field}: {value!r} is not a number') from exc
    if not math.isfinite(number):
        raise MeshError(f'{field}: {value!r}, expected a finite number')
    if minimum is not None:
        if number < minimum:
            raise MeshError(f'{field}: {value!r}, expected a number >= {minimum}')
    elif number < 0 or (number == 0 and not allow_zero):
        expected = 'a number >= 0' if allow_zero else 'a positive number'
        raise MeshError(f'{field}: {value!r}, expected {expected}')
    return number


def _kuhn_template() -> np.ndarray:
    """(6, 4, 3) local corners (0/1 per axis) of the Kuhn split of the unit cube: one element per
    permutation s of the axes, the path (0,0,0) -> e_s0 -> e_s0 + e_s1 -> (1,1,1), with vertices
    2 and 3 swapped for odd permutations so that every element is positively oriented."""
    permutations = [(0, 1, 2), (0, 2, 1), (1, 0, 2), (1, 2, 0), (2, 0, 1), (2, 1, 0)]
    template = np.zeros((6, 4, 3), dtype=np.int64)
    for t, perm in enumerate(permutations):  # 6 template elements, built once
        for step in range(1, 4):
            template[t, step] = template[t, step - 1]
            template[t, step, perm[step - 1]] = 1
        if np.linalg.det((template[t, 1:] - template[t, 0]).astype(float)) < 0:
            template[t, [2, 3]] = template[t, [3, 2]]
    return template


_KUHN_TEMPLATE = _kuhn_template()


def grid_mesh(axes) -> TetMesh:
    """The Kuhn-split grid on ``axes`` (the node coordinates along x, y, z)."""
    return _kuhn_grid_mesh(*axes)


def _kuhn_grid_mesh(x_nodes: np.ndarray, y_nodes: np.ndarray, z_nodes: np.ndarray) -> TetMesh:
    """The Kuhn-split tetrahedral mesh of the rectilinear grid with the given increasing node
    coordinates. Node (i, j, k) has index i + (nx+1) (j + (ny+1) k); hexahedron (i, j, k) has
    index i + nx (j + ny k) and owns elements 6 h .. 6 h + 5, so memory order follows space."""
    nx, ny, nz = x_nodes.size - 1, y_nodes.size - 1, z_nodes.size - 1
    px, pxy = nx + 1, (nx + 1) * (ny + 1)
    gx, gy, gz = np.meshgrid(x_nodes, y_nodes, z_nodes, indexing='ij')
    positions = np.stack([gx.ravel(order='F'), gy.ravel(order='F'), gz.ravel(order='F')], axis=1)

    i, j, k = np.meshgrid(np.arange(nx), np.arange(ny), np.arange(nz), indexing='ij')
    base = (i.ravel(order='F') + px * j.ravel(order='F') + pxy * k.ravel(order='F'))
    offsets = (_KUHN_TEMPLATE[..., 0] + px * _KUHN_TEMPLATE[..., 1]
               + pxy * _KUHN_TEMPLATE[..., 2])  # (6, 4)
    tetrahedra = (base[:, None, None] + offsets[None]).reshape(-1, 4)
    # Valid by construction; make_mesh re-checks (cheap) and would refuse an inverted element.
    return make_mesh(positions, tetrahedra, fix_orientation=False)


def box_mesh(size=(0.1, 0.1, 0.05), divisions=(20, 20, 10), origin=(0.0, 0.0, 0.0)) -> TetMesh:
    """A box [origin, origin + size] (metres) of nx * ny * nz equal hexahedra, each split into 6
    tetrahedra of volume (hexahedron volume) / 6 sharing its diagonal (0,0,0)-(1,1,1) (Kuhn /
    Freudenthal split). Every hexahedron is split alike, so the mesh is conforming.

    Node (i, j, k) has index i + (nx+1) (j + (ny+1) k); elements come hexahedron by hexahedron,
    x fastest. (nx+1)(ny+1)(nz+1) nodes, 6 nx ny nz elements.
    """
    return _kuhn_grid_mesh(*box_axes(size, divisions, origin))


def box_axes(size=(0.1, 0.1, 0.05), divisions=(20, 20, 10), origin=(0.0, 0.0, 0.0)) -> list:
    """The node coordinates along x, y and z of :func:`box_mesh` (cheap: the mesh's size is
    known from them before it is built, :func:`grid_elements`)."""
    size = _as_float_triple(size, 'size', positive=True)
    nx, ny, nz = _as_divisions(divisions)
    origin = _as_float_triple(origin, 'origin', positive=False)
    axes = [origin[a] + size[a] * (np.arange(n + 1) / n) for a, n in enumerate((nx, ny, nz))]
    for a, n in enumerate((nx, ny, nz)):
        axes[a][-1] = origin[a] + size[a]  # exact far face
    return axes


def grid_elements(axes) -> int:
    """The tetrahedra of the Kuhn-split grid on ``axes``: 6 per hexahedron."""
    return 6 * int(np.prod([len(axis) - 1 for axis in axes], dtype=np.float64))


def _graded_axis(lower: float, upper: float, focus: float, fine_size: float, growth: float,
                 max_size: float, fine_radius: float) -> np.ndarray:
    """Increasing node coordinates on [lower, upper], finest at ``focus``.

    Target cell width as a function of the distance d = |x - focus|:
        s(d) = fine_size                                          for d <= fine_radius,
        s(d) = min(fine_size + ln(growth) (d - fine_radius), max_size) beyond.
    The local cell count N(x) = integral of dx / s is the continuous form of "widths grow by
    `growth` per cell": in the growing zone ln s rises by ln(growth) per unit of N, so cells
    laid at equal steps of N have widths in exact geometric progression. The n = ceil(N_total)
    nodes are placed at equal steps c = N_total / n <= 1 of N, hence every width is at most
    s, the smallest is c * fine_size in (fine_size (1 - 1/n), fine_size], the largest at most
    max_size, and neighbouring widths differ by a factor of at most growth**c <= growth (since
    |d ln s / dN| <= ln(growth) everywhere). The cell that contains ``focus`` is the smallest.
    """
    rate = math.log(growth)
    n_fine = fine_radius / fine_size
    if rate > 0:
        growth_length = (max_size - fine_size) / rate  # distance over which s reaches max_size
        n_growth = math.log(max_size / fine_size) / rate

    def count(distance):  # N from the focus to `distance` >= 0
        beyond = np.maximum(distance - fine_radius, 0.0)
        near = np.minimum(distance, fine_radius) / fine_size
        if rate == 0:
            return near + beyond / fine_size
        growing = np.log1p(rate * np.minimum(beyond, growth_length) / fine_size) / rate
        capped = np.maximum(beyond - growth_length, 0.0) / max_size
        return near + growing + capped

    def distance_at(cells):  # inverse of count
        near = np.minimum(cells, n_fine) * fine_size
        beyond = np.maximum(cells - n_fine, 0.0)
        if rate == 0:
            return near + beyond * fine_size
        growing = fine_size / rate * np.expm1(rate * np.minimum(beyond, n_growth))
        capped = np.maximum(beyond - n_growth, 0.0) * max_size
        return near + growing + capped

    def signed_count(x):
        return np.sign(x - focus) * count(np.abs(x - focus))

    n_lower, n_upper = float(signed_count(lower)), float(signed_count(upper))
    total = n_upper - n_lower
    n_cells = max(1, math.ceil(total - 1e-9))
    steps = n_lower + total * (np.arange(n_cells + 1) / n_cells)
    nodes = focus + np.sign(steps) * distance_at(np.abs(steps))
    nodes[0], nodes[-1] = lower, upper
    return nodes


def graded_box_mesh(size=(0.1, 0.1, 0.05), divisions=(20, 20, 10), origin=(0.0, 0.0, 0.0), *,
                    focus=None, focus_radius: float = 0.0, growth: float = 1.2,
                    fine_size: float | None = None, grade_z: bool = False) -> TetMesh:
    """A Kuhn-split box like :func:`box_mesh` whose x and y node coordinates are graded toward
    ``focus`` (an (x, y) point in metres, default the centre of the x-y extent, e.g. where a
    needle enters the top face).

    Per graded axis (see :func:`_graded_axis` for the exact law):
      - within ``focus_radius`` (m) of the focus, cells have the smallest width ``fine_size``
        (m; default a quarter of the smallest coarse width of the graded axes);
      - farther away widths grow geometrically by ``growth`` (>= 1) per cell,
      - up to the coarse width size / divisions of that axis (``divisions`` sets the far-field
        resolution, as in box_mesh);
      - the number of cells follows, and all widths are scaled by one common factor in
        (1 - 1/n, 1] so that they fill the box exactly.
    z is uniform (divisions[2] cells) unless ``grade_z``, which grades it the same way toward the
    top face z = origin_z + size_z (fine layer of thickness ``focus_radius``).
    Node and element numbering as box_mesh, with nx, ny, nz the resulting cell counts.
    """
    return _kuhn_grid_mesh(*graded_box_axes(size, divisions, origin, focus=focus, focus_radius=focus_radius,
                                            growth=growth, fine_size=fine_size, grade_z=grade_z))


def graded_box_axes(size=(0.1, 0.1, 0.05), divisions=(20, 20, 10), origin=(0.0, 0.0, 0.0), *,
                    focus=None, focus_radius: float = 0.0, growth: float = 1.2,
                    fine_size: float | None = None, grade_z: bool = False) -> list:
    """The node coordinates along x, y and z of :func:`graded_box_mesh` (cheap, as
    :func:`box_axes`)."""
    size = _as_float_triple(size, 'size', positive=True)
    divisions = _as_divisions(divisions)
    origin = _as_float_triple(origin, 'origin', positive=False)
    coarse = size / np.array(divisions)
    upper = origin + size
    if focus is None:
        focus_xy = origin[:2] + 0.5 * size[:2]
    else:
        try:
            focus_xy = np.array(focus, dtype=np.float64).reshape(-1)
        except (TypeError, ValueError) as exc:
            raise MeshError(f'focus: {focus!r} is not numeric; expected (x, y) in metres') from exc
        if focus_xy.shape != (2,) or not np.isfinite(focus_xy).all():
            raise MeshError(f'focus: {focus!r}, expected 2 finite numbers (x, y) in metres')
        if ((focus_xy < origin[:2]) | (focus_xy > upper[:2])).any():
            raise MeshError(f'focus: {focus!r} lies outside the box, expected x in '
                            f'[{origin[0]}, {upper[0]}] and y in [{origin[1]}, {upper[1]}]')
    focus_radius = _as_positive_scalar(focus_radius, 'focus_radius', allow_zero=True)
    growth = _as_positive_scalar(growth, 'growth', minimum=1.0)
    graded_axes = [0, 1, 2] if grade_z else [0, 1]
    if fine_size is None:
        fine_size = 0.25 * float(coarse[graded_axes].min())
    fine_size = _as_positive_scalar(fine_size, 'fine_size')
    for a in graded_axes:
        if fine_size > coarse[a] * (1 + 1e-12):
            raise MeshError(f'fine_size: {fine_size!r} m exceeds the coarse width {coarse[a]!r} m '
                            f'(size / divisions) along {"xyz"[a]}; expected fine_size <= it')
    focus_point = [focus_xy[0], focus_xy[1], upper[2]]
    axes = []
    for a in range(3):
        if a in graded_axes:
            axes.append(_graded_axis(origin[a], upper[a], focus_point[a], fine_size, growth,
                                     max(coarse[a], fine_size), focus_radius))
        else:
            n = divisions[a]
            nodes = origin[a] + size[a] * (np.arange(n + 1) / n)
            nodes[-1] = upper[a]
            axes.append(nodes)
    return axes
