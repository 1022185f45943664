"""TensorMassModel: per-element precomputation and the internal forces of a tetrahedral mesh.

Holds, as plain arrays, what the force kernels need (shape-function gradients, V lambda, V mu,
rest edge Gram matrices for the mean ratio) plus the paper's assembled vertex and edge tensors,
and the preallocated per-thread buffers, so that a force evaluation allocates nothing.
"""
import numba
import numpy as np
import scipy.sparse
from numba import njit, prange

from tissue_sim_ros.engine.compiled import cache as compile_cache
from tissue_sim_ros.engine.model import critical_step
from tissue_sim_ros.engine.model import edge_form
from tissue_sim_ros.engine.model import kernels as forces
from tissue_sim_ros.engine.model import simd_lanes
from tissue_sim_ros.engine.mesh.tetmesh import TetMesh, make_mesh, mean_ratio
from tissue_sim_ros.engine.model.elements import LOCAL_EDGES, element_geometry, per_element_material
from tissue_sim_ros.engine.model.material import Material, MeanRatioLaw, Viscosity
from tissue_sim_ros.engine.model.relaxation import relaxation_for

#: the element constants' storage in the element pass (the arithmetic is float64 either way)
PRECISIONS = ('float64', 'float32')


class TensorMassModel:
    """The tensor-mass finite-element model of a tetrahedral mesh, any combination of the paper's.

    geometric: St Venant-Kirchhoff (Green-Lagrange strain) instead of small strain.
    physical: a MeanRatioLaw of Lamé corrections (None: no correction).
    viscosity: Kelvin-Voigt Viscosity (None: elastic only).
    relaxation: a PronySeries, or its terms as a list of ``{relative_modulus, time_constant_s}``
    mappings, relaxing the deviatoric stress (relaxation.py); None or empty: no relaxation and no
    cost. Its internal variables advance only when ``accumulate_forces`` is given a time step.
    nonlinearity_threshold: elements whose displacement gradient norm |H|_F is below it take
    the linear path (0: every element is non-linear, the full model exactly).
    inversion_safeguard: with the geometric model, continue the principal stresses linearly below
    a stretch of forces.STRETCH_CLAMP and treat inverted elements as reflected (Irving et al.
    2004), so strong compression pushes back instead of collapsing; the count of elements it
    changed in the last evaluation is ``safeguarded_count``.
    precision: 'float32' runs the element pass in single precision, its constants and its
    arithmetic (8 lanes a 256-bit instruction instead of 4); forces within about 1e-6 of the
    largest, displacements and the solver stay float64. The implicit integrators need float64.

    ``internal_forces(u, v)`` returns the internal force (n, 3) in newtons; for the linear model
    it is -K u, and the paper's vertex/edge-tensor form ``edge_form_forces(u)`` equals it.
    """

    def __init__(self, mesh: TetMesh, material, *, geometric=False, physical=None, viscosity=None,
                 nonlinearity_threshold=0.0, inversion_safeguard=True, n_threads=None, relaxation=None,
                 precision='float64'):
        if not isinstance(mesh, TetMesh):
            raise TypeError(f'mesh: expected a TetMesh, got {type(mesh).__name__}')
        if precision not in PRECISIONS:
            raise ValueError(f'precision = {precision!r}: expected one of {", ".join(PRECISIONS)}')
        self.precision = precision
        self.mesh = mesh
        self.materials, self.element_material = per_element_material(mesh, material)
        self.element_tags = np.asarray(mesh.element_tags)
        self.tetrahedra = np.ascontiguousarray(mesh.tetrahedra, dtype=np.int32)  # halves index traffic
        for name, values in self._element_data(self.tetrahedra, self.element_material).items():
            setattr(self, name, values)
        self._options_linear()
        self._set_options(geometric, physical, viscosity, nonlinearity_threshold)
        self.inversion_safeguard = bool(inversion_safeguard)
        self.relaxation = relaxation_for(relaxation, len(self.tetrahedra))
        self._n_threads = n_threads or numba.get_num_threads()
        self._allocate(self._n_threads)
        # compile (or load) the step's kernel now, not on the step loop; on a first start, a
        # second process compiles what a scene runs next meanwhile (compile_cache)
        with compile_cache.start_up():
            self._assemble_tensors()
            self.topology_version = 0
            zeros = np.zeros((mesh.n_nodes, 3))
            self.internal_forces(zeros, zeros)

    def _element_data(self, tetrahedra, material_index):
        """The per-element arrays of ``tetrahedra`` (at start, and for elements added later)."""
        positions = self.mesh.rest_positions
        shape_gradients, volumes, edge_gram = element_geometry(positions, tetrahedra)
        materials = self.materials
        return {
            'shape_gradients': shape_gradients,
            'volumes': volumes,
            'edge_gram': edge_gram,
            'volume_lambda': volumes * np.array([m.lame_lambda for m in materials])[material_index],
            'volume_mu': volumes * np.array([m.lame_mu for m in materials])[material_index],
            'mean_ratio_scale': 12.0 * (3.0 * volumes) ** (2.0 / 3.0) / mean_ratio(positions, tetrahedra),
            'element_mass': volumes * np.array([m.density for m in materials])[material_index],
        }

    # -- configuration --------------------------------------------------------------------
    def _options_linear(self):
        self.geometric = False
        self.physical = False
        self.viscous = False
        self.threshold_squared = 0.0
        self.law_kind = forces.LAW_NONE
        self.law_params = np.zeros(1)
        self.viscous_lambda = np.zeros(1)
        self.viscous_mu = np.zeros(1)

    def _set_options(self, geometric, physical, viscosity, nonlinearity_threshold):
        if not isinstance(geometric, bool):
            raise TypeError(f'geometric = {geometric!r}: expected True or False')
        if physical is not None and not isinstance(physical, MeanRatioLaw):
            raise TypeError(f'physical = {physical!r}: expected a MeanRatioLaw or None')
        if viscosity is not None and not isinstance(viscosity, Viscosity):
            raise TypeError(f'viscosity = {viscosity!r}: expected a Viscosity or None')
        self.geometric = geometric
        self.physical_law = physical
        self.physical = physical is not None and physical.kind != forces.LAW_NONE
        if self.physical:
            self.law_kind = physical.kind
            self.law_params = physical.parameters
        self.viscosity = viscosity
        self.viscous = viscosity is not None
        self._set_viscous_arrays()
        self.set_nonlinearity_threshold(nonlinearity_threshold)

    def set_nonlinearity_threshold(self, threshold):
        """Elements with |H|_F below ``threshold`` take the linear path from the next force
        evaluation on (a run-time argument of the kernel: nothing recompiles)."""
        if not (isinstance(threshold, (int, float)) and np.isfinite(threshold) and threshold >= 0):
            raise ValueError(f'nonlinearity_threshold = {threshold!r}: expected a finite '
                             'displacement-gradient norm >= 0')
        self.nonlinearity_threshold = float(threshold)
        self.threshold_squared = self.nonlinearity_threshold ** 2

    def _set_viscous_arrays(self):
        if self.viscous:
            self.viscous_lambda = self.volumes * self.viscosity.lambda_v
            self.viscous_mu = self.volumes * self.viscosity.mu_v

    def viscous_time_constant(self):
        """Largest Kelvin-Voigt time constant [s], max over elements of lambda_v / lambda and
        mu_v / mu (0 without viscosity): the viscous matrix is at most this times K."""
        if not self.viscous:
            return 0.0
        ratios = [self.viscous_mu / self.volume_mu]
        if self.viscosity.lambda_v > 0:
            ratios.append(self.viscous_lambda / np.maximum(self.volume_lambda, 1e-300))
        return float(max(r.max() for r in ratios))

    @property
    def n_threads(self) -> int:
        return self._n_threads

    def set_threads(self, n_threads: int) -> None:
        """Lay the element pass out for ``n_threads`` workers (per-thread buffers and chunks; the
        caller runs it with numba.set_num_threads(n_threads)). Not on the step loop: it allocates.
        The forces differ from another layout's only by the order of the sums (about 1e-16)."""
        if int(n_threads) != n_threads or n_threads < 1:
            raise ValueError(f'n_threads = {n_threads!r}: expected a whole number >= 1')
        if int(n_threads) != self._n_threads:
            self._n_threads = int(n_threads)
            self._allocate(self._n_threads)

    def _allocate(self, n_workers):
        n = self.mesh.n_nodes
        self.chunk_bounds, self.chunk_node_lo, self.chunk_node_hi, n_workers = forces.chunk_layout(
            self.tetrahedra, n, n_workers)
        n_chunks = len(self.chunk_bounds) - 1
        # rows padded to 4 and the node state's to 8: the element pass moves them as vectors (simd_lanes)
        self._buffers = np.zeros((n_workers, n, simd_lanes.BUFFER_WIDTH))
        self._node_state = np.zeros((n, simd_lanes.STATE_WIDTH), dtype=self.precision)
        self._nonlinear_counts = np.zeros(n_chunks, dtype=np.int64)
        self._safeguard_counts = np.zeros(n_chunks, dtype=np.int64)
        self._safeguard_scratch = np.zeros((n_workers, 6, 3, 3))
        m = len(self.tetrahedra)
        self._corrected_lambda = np.zeros(m)
        self._corrected_mu = np.zeros(m)
        self._slow_elements = np.zeros(m, dtype=np.int64)
        self._zero_velocity = np.zeros((n, 3))
        # 128 spare bytes a row: two threads' rows never share a cache line (sharing one made
        # the St Venant-Kirchhoff pass no faster on 2 threads than on 1). The row's precision is
        # the pass's arithmetic's (forces.ZERO...).
        spare = 128 // np.dtype(self.precision).itemsize
        self._work = np.zeros((n_workers, forces.N_WORK * forces.BLOCK + spare), dtype=self.precision)
        if self.relaxation is not None:
            self.relaxation.allocate(n_workers)
        self._pack_element_blocks()

    def _pack_element_blocks(self):
        """The element pass's per-element constants in block order, in the model's precision:
        float32 halves the stream the pass reads per element (20 constants, 160 bytes in float64;
        the indices are int32 already), and with the work rows in float32 (``_allocate``) the
        pass's arithmetic is float32 too."""
        self._element_blocks = forces.pack_element_blocks(
            self.shape_gradients, self.volume_lambda, self.volume_mu, self.viscous_lambda,
            self.viscous_mu, self.edge_gram, self.mean_ratio_scale).astype(self.precision)

    def set_element_lame(self, volume_lambda, volume_mu):
        """Replace every element's V lambda and V mu [N m] (e.g. per-element materials, or a law's
        corrections frozen at a state); the element blocks and the paper's vertex and edge
        tensors are rebuilt from them."""
        m = len(self.tetrahedra)
        values = {}
        for name, value in (('volume_lambda', volume_lambda), ('volume_mu', volume_mu)):
            value = np.asarray(value, dtype=float)
            if value.shape != (m,) or not np.all(np.isfinite(value)):
                raise ValueError(f'{name}: expected {m} finite values, got shape {value.shape}')
            values[name] = np.ascontiguousarray(value)
        self.volume_lambda = values['volume_lambda']
        self.volume_mu = values['volume_mu']
        self._pack_element_blocks()
        self._assemble_tensors()

    def _assemble_tensors(self):
        """Vertex tensors (n, 3, 3) and edge tensors (E, 3, 3), lambda and mu parts apart."""
        n = self.mesh.n_nodes
        pairs = np.stack([np.sort(self.tetrahedra[:, [j, k]], axis=1) for j, k in LOCAL_EDGES], axis=1)
        self.edges, inverse = np.unique(pairs.reshape(-1, 2), axis=0, return_inverse=True)
        self.element_edges = inverse.reshape(-1, 6).astype(np.int64)
        self.edges = self.edges.astype(np.int64)
        n_edges = len(self.edges)
        self.vertex_lambda = np.zeros((n, 3, 3))
        self.vertex_mu = np.zeros((n, 3, 3))
        self.edge_lambda = np.zeros((n_edges, 3, 3))
        self.edge_mu = np.zeros((n_edges, 3, 3))
        edge_form.accumulate_tensors(self.tetrahedra, self.shape_gradients, self.volume_lambda,
                                     self.volume_mu, self.element_edges,
                                     np.arange(self.mesh.n_elements), 1.0, self.vertex_lambda,
                                     self.vertex_mu, self.edge_lambda, self.edge_mu)
        self._build_adjacency()

    def _build_adjacency(self):
        """CSR list of the edges at each vertex, for the vertex/edge-tensor force loop."""
        ends = self.edges.ravel()
        order = np.argsort(ends, kind='stable')
        self.adjacency_edge = (order // 2).astype(np.int64)
        self.adjacency_ptr = np.concatenate(
            [[0], np.cumsum(np.bincount(ends, minlength=self.mesh.n_nodes))]).astype(np.int64)

    # -- topology change ------------------------------------------------------------------
    def remove_elements(self, elements):
        """Remove tetrahedra (cutting, carving): their forces, mass and surface go.

        The vertex and edge tensors are updated incrementally (each removed element's K_jk is
        subtracted); element arrays are compacted, and ``mesh`` is rebuilt so its surface follows.
        Returns the removed elements' (tetrahedra, material index, tags) for ``add_elements``.
        """
        elements = np.unique(np.asarray(elements, dtype=np.int64).ravel())
        bad = elements[(elements < 0) | (elements >= len(self.tetrahedra))]
        if bad.size:
            raise ValueError(f'elements: indices {bad[:10].tolist()} out of range [0, {len(self.tetrahedra)})')
        edge_form.accumulate_tensors(self.tetrahedra, self.shape_gradients, self.volume_lambda,
                                     self.volume_mu, self.element_edges, elements, -1.0,
                                     self.vertex_lambda, self.vertex_mu, self.edge_lambda, self.edge_mu)
        removed = (self.tetrahedra[elements].copy(), self.element_material[elements].copy(),
                   self.element_tags[elements].copy())
        keep = np.ones(len(self.tetrahedra), dtype=bool)
        keep[elements] = False
        if self.relaxation is not None:
            self.relaxation.keep(keep)
        for name in ('tetrahedra', 'shape_gradients', 'volumes', 'edge_gram', 'volume_lambda',
                     'volume_mu', 'mean_ratio_scale', 'element_mass', 'element_material',
                     'element_tags', 'element_edges'):
            setattr(self, name, np.ascontiguousarray(getattr(self, name)[keep]))
        self._topology_changed()
        return removed

    def add_elements(self, tetrahedra, material_index=None, tags=None):
        """Add tetrahedra over existing nodes (e.g. undo a removal); their K_jk are added to the tensors."""
        new = np.ascontiguousarray(np.asarray(tetrahedra).reshape(-1, 4), dtype=np.int32)
        material_index = np.zeros(len(new), dtype=np.int64) if material_index is None else np.asarray(material_index)
        tags = np.zeros(len(new), dtype=self.element_tags.dtype) if tags is None else np.asarray(tags)
        make_mesh(self.mesh.rest_positions, new, fix_orientation=False)   # refuses bad elements
        added = self._element_data(new, material_index)
        pairs = np.sort(np.stack([new[:, [j, k]] for j, k in LOCAL_EDGES], axis=1), axis=2).reshape(-1, 2)
        new_edges = self._edge_indices(pairs).reshape(-1, 6)
        edge_form.accumulate_tensors(new, added['shape_gradients'], added['volume_lambda'],
                                     added['volume_mu'], new_edges, np.arange(len(new)), 1.0,
                                     self.vertex_lambda, self.vertex_mu, self.edge_lambda, self.edge_mu)
        for name, values in added.items():
            setattr(self, name, np.concatenate([getattr(self, name), values]))
        self.tetrahedra = np.ascontiguousarray(np.concatenate([self.tetrahedra, new]))
        self.element_material = np.concatenate([self.element_material, material_index])
        self.element_tags = np.concatenate([self.element_tags, tags])
        self.element_edges = np.concatenate([self.element_edges, new_edges])
        if self.relaxation is not None:
            self.relaxation.add(len(new))
        self._topology_changed()

    def _edge_indices(self, pairs):
        """Global edge index of each sorted node pair (k, 2); pairs not yet known are appended
        with zero tensors. Vectorised: edges are keyed p * n + q and found by binary search."""
        n = self.mesh.n_nodes
        keys = self.edges[:, 0] * n + self.edges[:, 1]
        wanted = pairs[:, 0].astype(np.int64) * n + pairs[:, 1]
        order = np.argsort(keys)
        position = np.minimum(np.searchsorted(keys[order], wanted), len(keys) - 1)
        found = keys[order][position] == wanted
        fresh_keys, fresh_of = np.unique(wanted[~found], return_inverse=True)
        index = np.empty(len(pairs), dtype=np.int64)
        index[found] = order[position[found]]
        index[~found] = len(keys) + fresh_of
        if fresh_keys.size:
            self.edges = np.concatenate([self.edges, np.stack([fresh_keys // n, fresh_keys % n], axis=1)])
            zeros = np.zeros((fresh_keys.size, 3, 3))
            self.edge_lambda = np.concatenate([self.edge_lambda, zeros])
            self.edge_mu = np.concatenate([self.edge_mu, zeros])
        return index

    def _topology_changed(self):
        self._set_viscous_arrays()
        self.mesh = make_mesh(self.mesh.rest_positions, self.tetrahedra.astype(np.int64),
                              self.element_tags.astype(np.int32), fix_orientation=False)
        self._build_adjacency()
        self._allocate(self._n_threads)
        self.topology_version += 1

    # -- forces ---------------------------------------------------------------------------
    def internal_forces(self, displacement, velocity=None, out=None):
        """Internal force on every node (n, 3) [N]: -K u for the linear model."""
        if out is None:
            out = np.empty((self.mesh.n_nodes, 3))
        self.accumulate_forces(displacement, velocity)
        forces.reduce_buffers(self._buffers, self.chunk_node_lo, self.chunk_node_hi, out)
        return out

    def accumulate_forces(self, displacement, velocity=None, time_step=None, threshold_squared=None):
        """Run the element pass into the per-chunk buffers (see ``force_buffers``) without reducing.

        ``time_step`` [s]: a time step reached ``displacement``, ``time_step`` after the previous
        one (0: the first since reset): the relaxation's internal variables advance to it (the
        solver's step gives it). None: they are used as they are (a probe, a test).
        ``threshold_squared``: the non-linearity threshold's square for this pass (None: the
        model's; 0: every element non-linear, a force without the threshold's switch).
        """
        viscous = self.viscous and velocity is not None
        self._run_kernel(self.geometric, self.physical, viscous, displacement,
                         velocity if viscous else self._zero_velocity,
                         self.threshold_squared if threshold_squared is None else threshold_squared,
                         self.inversion_safeguard and self.geometric)
        if self.relaxation is not None:
            self.relaxation.accumulate(self, displacement, time_step)

    def reset_relaxation(self):
        """Forget the relaxation history (the rest state); nothing without relaxation."""
        if self.relaxation is not None:
            self.relaxation.reset()

    def _run_kernel(self, geometric, physical, viscous, displacement, velocity, threshold_squared, safeguard):
        kernel, args = self._kernel_call(geometric, physical, viscous, displacement, velocity, threshold_squared,
                                         safeguard)
        if (kernel, self.precision) in compile_cache.LOADED:
            kernel(*args)
        else:     # first use in this process: the cached code, compiled apart if need be
            what = (f'element pass, {forces.model_name(geometric, physical, viscous)} model'
                    + ('' if self.precision == 'float64' else f', {self.precision}'))
            code = (f'from {__name__} import compile_element_pass; '
                    f'compile_element_pass{(geometric, physical, viscous, self.precision)!r}')
            compile_cache.call_compiled_apart(
                kernel, args, self.precision, what, code,
                helper_compiles=(geometric, physical, viscous) == (False, False, False) and self.precision == 'float64')

    def _kernel_call(self, geometric, physical, viscous, displacement, velocity, threshold_squared, safeguard):
        kernel = forces.element_kernel(geometric, physical, viscous)
        return kernel, (self.tetrahedra, self._element_blocks, displacement, velocity, threshold_squared,
                        self.law_kind, self.law_params, self.chunk_bounds, self._work, self._buffers,
                        self._nonlinear_counts, safeguard, self._safeguard_counts, self._slow_elements,
                        self._corrected_lambda, self._corrected_mu, self.shape_gradients, self.volume_lambda,
                        self.volume_mu, self.viscous_lambda, self.viscous_mu, self._safeguard_scratch,
                        self._node_state)

    def force_pass_call(self, displacement, velocity):
        """(kernel, arguments) of the pass ``accumulate_forces(displacement, velocity)`` runs, for
        a caller that repeats it (a slice of substeps, engine.compiled_substep); None until this
        process has run that pass once (its code loaded), or with relaxation (its update is not
        in the pass). Valid until the elements change (``topology_version``)."""
        viscous = self.viscous and velocity is not None
        kernel, args = self._kernel_call(self.geometric, self.physical, viscous, displacement,
                                         velocity if viscous else self._zero_velocity, self.threshold_squared,
                                         self.inversion_safeguard and self.geometric)
        if self.relaxation is not None or (kernel, self.precision) not in compile_cache.LOADED:
            return None
        return kernel, args

    @property
    def safeguarded_count(self):
        """Elements whose stress the inversion safeguard changed in the last force evaluation."""
        return int(self._safeguard_counts.sum())

    @property
    def force_buffers(self):
        """(buffers, node_lo, node_hi): what ``forces.take_node_force`` needs to gather node forces."""
        return self._buffers, self.chunk_node_lo, self.chunk_node_hi

    def linear_forces(self, displacement, out=None):
        """-K u of the linear (small-strain, elastic) part, whatever the model's options."""
        if out is None:
            out = np.empty((self.mesh.n_nodes, 3))
        self._run_kernel(False, False, False, displacement, self._zero_velocity, 0.0, False)
        forces.reduce_buffers(self._buffers, self.chunk_node_lo, self.chunk_node_hi, out)
        return out

    @property
    def nonlinear_fraction(self):
        """Fraction of elements that took the non-linear path in the last force evaluation."""
        return float(self._nonlinear_counts.sum()) / max(1, self.mesh.n_elements)

    def edge_form_forces(self, displacement, out=None):
        """-K u from the assembled vertex and edge tensors (the paper's form, linear model)."""
        if out is None:
            out = np.empty((self.mesh.n_nodes, 3))
        edge_form.edge_forces(self.vertex_lambda, self.vertex_mu, self.edge_lambda, self.edge_mu,
                              self.edges, self.adjacency_ptr, self.adjacency_edge, displacement, out)
        return out

    def stiffness_matrix(self):
        """The global linear stiffness K (3n x 3n, scipy CSR) from the vertex and edge tensors."""
        n = self.mesh.n_nodes
        vertex = self.vertex_lambda + self.vertex_mu
        edge = self.edge_lambda + self.edge_mu
        r, s = np.meshgrid(np.arange(3), np.arange(3), indexing='ij')
        p, q = self.edges[:, 0], self.edges[:, 1]
        nodes = np.arange(n)
        rows = np.concatenate([(3 * nodes[:, None, None] + r).ravel(),
                               (3 * p[:, None, None] + r).ravel(), (3 * q[:, None, None] + s).ravel()])
        cols = np.concatenate([(3 * nodes[:, None, None] + s).ravel(),
                               (3 * q[:, None, None] + s).ravel(), (3 * p[:, None, None] + r).ravel()])
        values = np.concatenate([vertex.ravel(), edge.ravel(), edge.ravel()])
        return scipy.sparse.csr_matrix((values, (rows, cols)), shape=(3 * n, 3 * n))

    # -- mass, energy, stability ------------------------------------------------------------
    def lumped_masses(self):
        """Node masses (n,) [kg]: each element's mass rho V split equally over its 4 vertices."""
        return np.bincount(self.tetrahedra.ravel(), weights=np.repeat(self.element_mass / 4.0, 4),
                           minlength=self.mesh.n_nodes)

    def strain_energy(self, displacement):
        """Elastic energy [J] and the number of inverted elements (det F <= 0) at ``displacement``.

        Linear model: sum V (lambda/2 tr(eps)^2 + mu eps:eps) = u.K u / 2. With relaxation, the
        stored (free) energy: the relaxed part of mu left out, the energy the Maxwell branches
        hold added (relaxation.py), so it never exceeds the work put in.
        """
        energy, inverted = _strain_energy(*self._strain_energy_arguments(displacement))
        if self.relaxation is not None:
            energy += self.relaxation.energy_change(self, displacement)
        return energy, inverted

    def strain_energy_call(self, displacement):
        """(kernel, arguments) of :meth:`strain_energy`'s element pass, for a caller that repeats
        it (the watchdog's energy-check steps in a slice of substeps, engine.compiled_substep); None
        with relaxation (its energy is not in the pass)."""
        return None if self.relaxation is not None else (_strain_energy, self._strain_energy_arguments(displacement))

    def _strain_energy_arguments(self, displacement):
        return self.tetrahedra, self.shape_gradients, self.volume_lambda, self.volume_mu, displacement, self.geometric

    def critical_time_step(self, method='lanczos', mass_factor=None):
        """Critical (largest stable) explicit time step [s] of the linearised model, 2 / omega_max
        (critical_step.py: 'lanczos', the estimate; 'element_bound', a guaranteed lower bound).
        Stiffening under deformation (non-linear models) lowers the limit: keep a safety margin.
        ``mass_factor`` (n,): a factor on each node's lumped mass (lanczos only; None: 1)."""
        if method == 'element_bound' and mass_factor is None:
            return critical_step.element_bound(self)
        if method != 'lanczos':
            raise ValueError(f"method = {method!r}: expected 'lanczos', or 'element_bound' without a mass_factor")
        return critical_step.lanczos(self, mass_factor)


@njit(cache=True, parallel=True, fastmath=forces.FASTMATH, boundscheck=False, nogil=True)
def _strain_energy(tetrahedra, shape_gradients, volume_lambda, volume_mu, displacement, geometric):
    """Sum of V (lambda/2 tr(E)^2 + mu E:E) with E = sym(H) (+ H^T H / 2 if geometric); inverted count."""
    energy = 0.0
    inverted = 0
    for e in prange(tetrahedra.shape[0]):
        g = shape_gradients[e]
        h00, h01, h02, h10, h11, h12, h20, h21, h22 = forces.element_gradient(
            displacement, tetrahedra[e, 0], tetrahedra[e, 1], tetrahedra[e, 2], tetrahedra[e, 3],
            g[0, 0], g[0, 1], g[0, 2], g[1, 0], g[1, 1], g[1, 2], g[2, 0], g[2, 1], g[2, 2])
        if geometric:
            e00, e11, e22, e01, e02, e12 = forces.green_strain(h00, h01, h02, h10, h11, h12, h20, h21, h22)
        else:
            e00, e11, e22 = h00, h11, h22
            e01, e02, e12 = 0.5 * (h01 + h10), 0.5 * (h02 + h20), 0.5 * (h12 + h21)
        trace = e00 + e11 + e22
        energy += (0.5 * volume_lambda[e] * trace * trace
                   + volume_mu[e] * (e00 * e00 + e11 * e11 + e22 * e22 + 2.0 * (e01 * e01 + e02 * e02 + e12 * e12)))
        if forces.deformation_determinant(h00, h01, h02, h10, h11, h12, h20, h21, h22) <= 0.0:
            inverted += 1
    return energy, inverted


def compile_element_pass(geometric, physical, viscous, precision='float64'):
    """In a compile process (engine.compiled.cache): compile one model's element pass into the
    cache, on a one-element model (the arrays it passes have the types every model's have)."""
    from tissue_sim_ros.engine.mesh.generators import box_mesh
    TensorMassModel(box_mesh((1.0, 1.0, 1.0), (1, 1, 1)), Material(1e4, 0.3, 1000.0), geometric=geometric,
                    physical=MeanRatioLaw.exponential(mu_amplitude=1.0, mu_rate=1.0) if physical else None,
                    viscosity=Viscosity(1.0, 1.0) if viscous else None, precision=precision)
