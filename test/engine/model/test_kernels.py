"""The element kernels (engine/model/kernels.py) against independent truth: the patch test,
uniaxial compression and stretch, rigid rotations, energy gradients, the mean-ratio law's frozen
form, dissipation rates, the non-linearity threshold, and forces that do not depend on threads,
blocks or precision beyond their rounding."""

import numpy as np
import pytest

import tissue_sim_ros as ts
from support.solvers import static_solve
from tissue_sim_ros.engine.model.reference import all_shape_gradients, picinbono_forces


def test_patch_test_affine_field(jittered_block, liver):
    """u = G X + c: zero force on interior nodes; on the boundary the internal force balances
    the exact traction sigma n integrated with the linear shape functions (A/3 per vertex)."""
    mesh = jittered_block
    model = ts.TensorMassModel(mesh, liver)
    grad = np.array([[0.010, -0.004, 0.002], [0.003, -0.006, 0.001], [-0.002, 0.005, 0.008]])
    u = mesh.rest_positions @ grad.T + np.array([1e-3, -2e-3, 5e-4])
    force = model.internal_forces(u)
    strain = 0.5 * (grad + grad.T)
    stress = liver.lame_lambda * np.trace(strain) * np.eye(3) + 2 * liver.lame_mu * strain
    expected = np.zeros_like(force)
    tri = mesh.surface_triangles()
    p = mesh.rest_positions[tri]
    area_normal = 0.5 * np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])   # n A, outward
    traction = area_normal @ stress.T / 3.0                                # sigma n A / 3
    for k in range(3):
        np.add.at(expected, tri[:, k], -traction)
    scale = np.abs(expected).max()
    interior = np.setdiff1d(np.arange(mesh.n_nodes), mesh.surface_nodes())
    assert len(interior) > 0
    assert np.abs(force[interior]).max() < 1e-12 * scale
    assert np.abs(force - expected).max() < 1e-12 * scale


def test_uniaxial_compression_reaction_equals_E_A_strain(liver):
    """Frictionless plates on a block with free lateral faces: F = E A strain, lateral strain -nu strain."""
    size = (0.04, 0.03, 0.02)
    mesh = ts.box_mesh(size=size, divisions=(4, 3, 4))
    model = ts.TensorMassModel(mesh, liver)
    x = mesh.rest_positions
    strain = 0.05
    bottom = np.flatnonzero(np.isclose(x[:, 2], 0.0))
    top = np.flatnonzero(np.isclose(x[:, 2], size[2]))
    origin = np.flatnonzero(np.all(np.isclose(x, 0.0), axis=1))
    corner_x = np.flatnonzero(np.all(np.isclose(x, [size[0], 0, 0]), axis=1))
    dofs = np.concatenate([3 * bottom + 2, 3 * top + 2, 3 * origin, 3 * origin + 1, 3 * corner_x + 1])
    values = np.concatenate([np.zeros(len(bottom)), np.full(len(top), -strain * size[2]),
                             np.zeros(3)])
    u = static_solve(model, dofs, values)
    force = model.internal_forces(u)
    reaction = force[top].sum(axis=0)
    area = size[0] * size[1]
    assert reaction[2] == pytest.approx(liver.young_modulus * area * strain, rel=1e-9)
    assert np.abs(reaction[:2]).max() < 1e-9 * reaction[2]
    lateral = (u[corner_x, 0] - u[origin, 0]) / size[0]
    assert lateral[0] == pytest.approx(liver.poisson_ratio * strain, rel=1e-9)


def test_forces_do_not_depend_on_thread_count(liver):
    """Per-chunk buffers must not race: 1 and 7 chunks give the same forces to round-off."""
    mesh = ts.box_mesh(size=(0.05, 0.05, 0.05), divisions=(8, 8, 8))
    u = np.random.default_rng(1).normal(scale=1e-3, size=(mesh.n_nodes, 3))
    one = ts.TensorMassModel(mesh, liver, n_threads=1).internal_forces(u)
    many = ts.TensorMassModel(mesh, liver, n_threads=7)
    first = many.internal_forces(u)
    second = many.internal_forces(u)                       # buffers are cleared between calls
    assert np.abs(one - first).max() < 1e-12 * np.abs(one).max()
    assert np.array_equal(first, second)


def _rotation(axis, angle):
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * k @ k


def _boundary_forces(mesh, stress_times_normal):
    """-sum over surface triangles of (P N) A / 3 per vertex: the consistent nodal forces of a
    homogeneous first Piola-Kirchhoff stress P on the reference boundary."""
    tri = mesh.surface_triangles()
    p = mesh.rest_positions[tri]
    area_normal = 0.5 * np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    traction = stress_times_normal(area_normal) / 3.0
    out = np.zeros((mesh.n_nodes, 3))
    for k in range(3):
        np.add.at(out, tri[:, k], -traction)
    return out


@pytest.mark.parametrize('angle', [0.1, 0.5, np.pi / 2, 2.5, np.pi])
def test_rigid_rotation_no_geometric_force_linear_ghost_forces(jittered_block, liver, angle):
    mesh = jittered_block
    rotation = _rotation([1.0, 2.0, -0.5], angle)
    centre = mesh.rest_positions.mean(axis=0)
    u = (mesh.rest_positions - centre) @ rotation.T + centre - mesh.rest_positions
    geometric = ts.TensorMassModel(mesh, liver, geometric=True).internal_forces(u)
    linear = ts.TensorMassModel(mesh, liver).internal_forces(u)
    # force scale: mu |u| h, the size of the ghost forces of the linear model (FORMULAS.md)
    h = np.cbrt(mesh.volumes().mean())
    scale = liver.lame_mu * np.abs(u).max() * h
    assert np.abs(geometric).max() < 1e-12 * scale
    ghost = np.abs(linear).max() / scale
    assert ghost > 0.1 * angle          # of order one: the linear model is not rotation invariant
    print(f'rotation {angle:.2f} rad: StVK residual {np.abs(geometric).max() / scale:.1e}, '
          f'linear ghost force {ghost:.2f} mu |u| h')


@pytest.mark.parametrize('stretch', [0.7, 0.9, 1.1, 1.5])
def test_uniaxial_stretch_exact_first_piola_and_lateral_strain(jittered_block, liver, stretch):
    """Homogeneous uniaxial stress: E_11 = (s^2-1)/2, E_22 = E_33 = -nu E_11, P_11 = Y s (s^2-1)/2.
    The mesh must be in equilibrium with exactly this traction on its boundary."""
    mesh = jittered_block
    lam, mu, nu = liver.lame_lambda, liver.lame_mu, liver.poisson_ratio
    young = mu * (3 * lam + 2 * mu) / (lam + mu)
    e11 = 0.5 * (stretch ** 2 - 1.0)
    lateral = np.sqrt(1.0 + 2.0 * (-nu * e11))
    deformation = np.diag([stretch, lateral, lateral])
    u = mesh.rest_positions @ (deformation - np.eye(3)).T
    p11 = young * stretch * e11
    first_piola = np.diag([p11, 0.0, 0.0])
    force = ts.TensorMassModel(mesh, liver, geometric=True).internal_forces(u)
    expected = _boundary_forces(mesh, lambda area_normal: area_normal @ first_piola.T)
    scale = np.abs(expected).max()
    # the lateral Green strain is set to -nu E_11; free lateral faces <=> forces match P = diag(P11, 0, 0)
    print(f'uniaxial stretch {stretch}: nodal forces vs the P11 traction, lateral faces free: '
          f'{np.abs(force - expected).max() / scale:.1e} relative')
    assert np.abs(force - expected).max() < 1e-9 * scale
    x_max = np.isclose(mesh.rest_positions[:, 0], mesh.rest_positions[:, 0].max())
    face_area = np.ptp(mesh.rest_positions[:, 1]) * np.ptp(mesh.rest_positions[:, 2])
    assert -force[x_max, 0].sum() == pytest.approx(p11 * face_area, rel=1e-9)


def test_geometric_forces_are_minus_energy_gradient(jittered_block, liver):
    model = ts.TensorMassModel(jittered_block, liver, geometric=True, inversion_safeguard=False)
    rng = np.random.default_rng(5)
    u = rng.normal(scale=0.004, size=(jittered_block.n_nodes, 3))        # strains ~ 0.3
    force = model.internal_forces(u)
    step = 1e-7
    worst = 0.0
    for node, axis in [(0, 0), (7, 1), (20, 2), (33, 0), (jittered_block.n_nodes - 1, 2)]:
        plus, minus = u.copy(), u.copy()
        plus[node, axis] += step
        minus[node, axis] -= step
        gradient = (model.strain_energy(plus)[0] - model.strain_energy(minus)[0]) / (2 * step)
        worst = max(worst, abs(-gradient - force[node, axis]) / abs(force[node, axis]))
        print(f'St Venant-Kirchhoff force vs -dW/du (central differences): worst so far {worst:.1e} relative')
        assert -gradient == pytest.approx(force[node, axis], rel=1e-6, abs=1e-9 * np.abs(force).max())


def _independent_physical_force(mesh, material, law, u, geometric):
    """(K + dlambda A + dmu B) u, or its St Venant-Kirchhoff analogue, with the corrections from
    meshio-free numpy: mesh.mean_ratio of the deformed positions over the rest mean ratio."""
    distortion = np.maximum(0.0, 1.0 - mesh.mean_ratio(mesh.rest_positions + u) / mesh.mean_ratio())
    g_lambda, g_mu = law.corrections(distortion)
    frozen = ts.TensorMassModel(mesh, material, geometric=geometric)
    frozen.set_element_lame(frozen.volume_lambda * (1.0 + g_lambda), frozen.volume_mu * (1.0 + g_mu))
    return frozen, distortion


@pytest.mark.parametrize('law', [ts.MeanRatioLaw.polynomial([2.0, 30.0], [5.0, -3.0, 40.0]),
                                 ts.MeanRatioLaw.exponential(0.5, 8.0, 1.5, 12.0)])
def test_physical_law_scales_forces_as_K_plus_dlambda_A_plus_dmu_B(jittered_block, liver, law):
    mesh = jittered_block
    rng = np.random.default_rng(2)
    u = rng.normal(scale=0.002, size=(mesh.n_nodes, 3))
    physical = ts.TensorMassModel(mesh, liver, physical=law).internal_forces(u)
    frozen, distortion = _independent_physical_force(mesh, liver, law, u, geometric=False)
    assert distortion.max() > 0.05                     # the law is really exercised
    assert 0.2 < np.mean(distortion == 0) < 0.8        # and so is its s = 0 side (quality went up)
    expected = -(frozen.stiffness_matrix() @ u.ravel()).reshape(-1, 3)
    print(f'{law.description.split("(")[0]} law: kernel vs (K + dlambda A + dmu B) u '
          f'{np.abs(physical - expected).max() / np.abs(expected).max():.1e} relative')
    assert np.abs(physical - expected).max() < 1e-10 * np.abs(expected).max()
    # with the corrections frozen, the force is minus the gradient of the frozen energy
    assert frozen.strain_energy(u)[0] == pytest.approx(-0.5 * np.sum(u * expected), rel=1e-12)
    # full model: St Venant-Kirchhoff with the corrected coefficients
    full = ts.TensorMassModel(mesh, liver, geometric=True, physical=law,
                              inversion_safeguard=False).internal_forces(u)
    frozen_geometric, _ = _independent_physical_force(mesh, liver, law, u, geometric=True)
    reference = picinbono_forces(frozen_geometric.tetrahedra, frozen_geometric.shape_gradients,
                                 frozen_geometric.volume_lambda, frozen_geometric.volume_mu, u)
    print(f'{law.description.split("(")[0]} law, full model vs frozen K/c/d reference: '
          f'{np.abs(full - reference).max() / np.abs(reference).max():.1e} relative')
    assert np.abs(full - reference).max() < 1e-10 * np.abs(reference).max()


def test_viscous_dissipation_rate_and_rigid_motion(jittered_block, liver):
    mesh = jittered_block
    viscosity = ts.Viscosity(lambda_v=3.0, mu_v=7.0)
    model = ts.TensorMassModel(mesh, liver, viscosity=viscosity)
    rng = np.random.default_rng(9)
    v = rng.normal(scale=0.01, size=(mesh.n_nodes, 3))
    force = model.internal_forces(np.zeros_like(v), v)
    a = all_shape_gradients(model.shape_gradients)
    rate = np.einsum('mkr,mks->mrs', v[model.tetrahedra], a)            # dH/dt per element
    strain_rate = 0.5 * (rate + rate.transpose(0, 2, 1))
    trace = np.trace(strain_rate, axis1=1, axis2=2)
    dissipation = np.sum(model.volumes * (viscosity.lambda_v * trace ** 2
                                          + 2 * viscosity.mu_v * np.sum(strain_rate ** 2, axis=(1, 2))))
    print(f'viscous power vs dissipation rate: {abs(-np.sum(force * v) / dissipation - 1):.1e} relative')
    assert -np.sum(force * v) == pytest.approx(dissipation, rel=1e-12)
    assert dissipation > 0
    # rigid motion: translation plus infinitesimal rotation rate, at rest (linear model)
    omega, drift = np.array([0.3, -1.0, 0.5]), np.array([0.01, 0.02, -0.03])
    rigid_v = np.cross(omega, mesh.rest_positions) + drift
    scale = np.abs(force).max()
    assert np.abs(model.internal_forces(np.zeros_like(v), rigid_v)).max() < 1e-12 * scale
    # geometric model: a finite rotation R moving rigidly (v = omega x (current x)) gives no force
    geometric = ts.TensorMassModel(mesh, liver, geometric=True, viscosity=viscosity)
    rotation = _rotation([0.2, 1.0, 0.4], 1.1)
    current = mesh.rest_positions @ rotation.T
    moving = geometric.internal_forces(current - mesh.rest_positions, np.cross(omega, current) + drift)
    print(f'rigid motion, viscous force: linear model {np.abs(model.internal_forces(np.zeros_like(v), rigid_v)).max() / scale:.1e}'
          f' of the deforming case; geometric model, finite rotation: {np.abs(moving).max():.1e} N')
    assert np.abs(moving).max() < 1e-12 * liver.lame_mu * np.abs(current).max() * np.cbrt(mesh.volumes().mean())


def test_threshold_zero_is_full_model_and_large_threshold_is_linear(jittered_block, liver):
    mesh = jittered_block
    law = ts.MeanRatioLaw.exponential(0.5, 8.0, 1.5, 12.0)
    viscosity = ts.Viscosity(lambda_v=1.0, mu_v=2.0)
    rng = np.random.default_rng(4)
    u = rng.normal(scale=0.003, size=(mesh.n_nodes, 3))
    v = rng.normal(scale=0.01, size=(mesh.n_nodes, 3))
    full = ts.TensorMassModel(mesh, liver, geometric=True, physical=law, viscosity=viscosity)
    thresholded = ts.TensorMassModel(mesh, liver, geometric=True, physical=law, viscosity=viscosity,
                                     nonlinearity_threshold=0.0)
    assert np.array_equal(full.internal_forces(u, v), thresholded.internal_forces(u, v))
    assert thresholded.nonlinear_fraction == 1.0
    # against the independent full-model reference
    frozen, _ = _independent_physical_force(mesh, liver, law, u, geometric=True)
    elastic = ts.TensorMassModel(mesh, liver, geometric=True, physical=law,
                                 inversion_safeguard=False).internal_forces(u)
    reference = picinbono_forces(frozen.tetrahedra, frozen.shape_gradients, frozen.volume_lambda,
                                 frozen.volume_mu, u)
    print(f'threshold 0: bit-identical to the full model; elastic part vs K/c/d reference '
          f'{np.abs(elastic - reference).max() / np.abs(reference).max():.1e} relative')
    assert np.abs(elastic - reference).max() < 1e-10 * np.abs(reference).max()
    huge = ts.TensorMassModel(mesh, liver, geometric=True, physical=law, viscosity=viscosity,
                              nonlinearity_threshold=1e9)
    linear = ts.TensorMassModel(mesh, liver, viscosity=viscosity)
    # each model runs its own compiled kernel, so equal to round-off rather than bit for bit
    expected = linear.internal_forces(u, v)
    difference = np.abs(huge.internal_forces(u, v) - expected).max() / np.abs(expected).max()
    print(f'threshold 1e9 vs linear model: {difference:.1e} relative')
    assert difference < 1e-14
    assert huge.nonlinear_fraction == 0.0


def test_threshold_selects_deformed_elements(jittered_block, liver):
    """The fraction on the non-linear path equals the count of elements with |H|_F >= threshold,
    and each element's force is the full model's or the linear one's accordingly."""
    mesh = jittered_block
    centre = mesh.rest_positions.mean(axis=0)
    distance = np.linalg.norm(mesh.rest_positions - centre, axis=1)
    u = np.zeros((mesh.n_nodes, 3))
    u[:, 2] = -0.004 * np.exp(-(distance / 0.006) ** 2)             # a needle-like local dent
    threshold = 0.05
    model = ts.TensorMassModel(mesh, liver, geometric=True, nonlinearity_threshold=threshold)
    force = model.internal_forces(u)
    a = all_shape_gradients(model.shape_gradients)
    norms = np.linalg.norm(np.einsum('mkr,mks->mrs', u[model.tetrahedra], a), axis=(1, 2))
    selected = norms >= threshold
    assert 0 < selected.sum() < mesh.n_elements
    assert model.nonlinear_fraction == pytest.approx(selected.mean(), abs=1e-15)
    nonlinear_part = picinbono_forces(model.tetrahedra[selected], model.shape_gradients[selected],
                                      model.volume_lambda[selected], model.volume_mu[selected], u)
    linear_model = ts.TensorMassModel(mesh, liver)
    linear_model.set_element_lame(np.where(selected, 0.0, linear_model.volume_lambda),
                                  np.where(selected, 0.0, linear_model.volume_mu))
    expected = nonlinear_part + linear_model.internal_forces(u)
    assert np.abs(force - expected).max() < 1e-12 * np.abs(expected).max()


@pytest.mark.parametrize('geometric, quantile', [(True, 0.5), (True, 0.97), (False, 0.5)])
def test_blocks_and_workers_do_not_change_the_forces(liver, geometric, quantile):
    """The element pass runs in SIMD blocks of 8 elements dealt round-robin to workers; the forces
    must not depend on which block, lane, chunk or worker an element falls in, nor on the padded
    lanes of the last block. Truth: each element alone (a one-element model, seven lanes of
    padding), summed per node. The full model (and the physically non-linear one) with viscosity
    and a threshold that mixes linear and non-linear lanes within blocks (at the median), or that
    leaves most blocks without a non-linear lane (at the 97th percentile); the full model's
    strains are large enough to bring in the safeguard."""
    mesh = ts.box_mesh(size=(0.03, 0.03, 0.02), divisions=(3, 3, 2))      # 108 = 13 * 8 + 4
    assert mesh.n_elements % 8 != 0
    rng = np.random.default_rng(5)
    u = rng.normal(scale=2e-3, size=(mesh.n_nodes, 3))
    v = rng.normal(scale=1e-2, size=(mesh.n_nodes, 3))
    a = all_shape_gradients(ts.TensorMassModel(mesh, liver).shape_gradients)
    norms = np.linalg.norm(np.einsum('mkr,mks->mrs', u[mesh.tetrahedra], a), axis=(1, 2))
    threshold = float(np.quantile(norms, quantile))
    options = dict(geometric=geometric, physical=ts.MeanRatioLaw.exponential(0.5, 8.0, 1.5, 12.0),
                   viscosity=ts.Viscosity(lambda_v=5.0, mu_v=2.0), nonlinearity_threshold=threshold)
    expected = np.zeros((mesh.n_nodes, 3))
    safeguarded = 0
    for tet in mesh.tetrahedra:
        alone = ts.TensorMassModel(ts.make_mesh(mesh.rest_positions[tet], np.arange(4)[None]), liver, **options)
        expected[tet] += alone.internal_forces(u[tet], v[tet])
        safeguarded += alone.safeguarded_count
    assert (safeguarded > 0) == geometric
    blocks = (norms[:mesh.n_elements // 8 * 8].reshape(-1, 8) >= threshold).any(axis=1)
    assert blocks.all() if quantile == 0.5 else 0 < blocks.sum() < len(blocks) // 2
    for n_threads in (1, 2, 3):
        model = ts.TensorMassModel(mesh, liver, n_threads=n_threads, **options)
        forces = model.internal_forces(u, v)
        assert np.abs(forces - expected).max() < 1e-12 * np.abs(expected).max()
        assert model.nonlinear_fraction == pytest.approx(np.mean(norms >= threshold), abs=1e-15)
        assert model.safeguarded_count == safeguarded


def test_float32_pass_is_single_precision_arithmetic_within_its_rounding(liver):
    """precision='float32' runs the element pass in float32, constants and arithmetic: its forces
    are within float32's resolution of the float64 model's (1e-6 of the largest force; 4e-7 is
    seen), for the full model with viscosity, the law and a threshold, on strains large enough for
    the safeguard; and they are not the float64 arithmetic on float32-rounded constants (which
    agrees with float64 arithmetic to 1e-14), so the arithmetic really is float32. The implicit
    integrators, whose Newton tangent is a 1e-8 difference, refuse it."""
    mesh = ts.box_mesh(size=(0.03, 0.03, 0.02), divisions=(3, 3, 2))
    rng = np.random.default_rng(7)
    u = rng.normal(scale=2e-3, size=(mesh.n_nodes, 3))
    v = rng.normal(scale=1e-2, size=(mesh.n_nodes, 3))
    options = dict(geometric=True, physical=ts.MeanRatioLaw.exponential(0.5, 8.0, 1.5, 12.0),
                   viscosity=ts.Viscosity(lambda_v=5.0, mu_v=2.0), nonlinearity_threshold=0.01)
    single = ts.TensorMassModel(mesh, liver, precision='float32', **options)
    assert single._element_blocks.dtype == np.float32 and single._work.dtype == np.float32
    double = ts.TensorMassModel(mesh, liver, **options)
    exact = double.internal_forces(u, v)
    double._element_blocks = double._element_blocks.astype(np.float32).astype(np.float64)
    rounded_constants = double.internal_forces(u, v)
    forces = single.internal_forces(u, v)
    assert single.safeguarded_count > 0
    scale = np.abs(exact).max()
    assert 0 < np.abs(forces - exact).max() < 1e-6 * scale
    assert np.abs(forces - rounded_constants).max() > 1e-9 * scale
    with pytest.raises(ValueError, match='precision'):
        ts.Simulation(single, integrator='implicit')
    with pytest.raises(ValueError, match='precision'):
        ts.TensorMassModel(mesh, liver, precision='float16')
