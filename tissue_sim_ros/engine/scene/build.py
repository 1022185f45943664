"""One builder: a scene's checked keys -> mesh, materials, model, simulation, needle parts.

Every caller that needs a material, a model or a simulation from scene keys builds it here
(the scene itself, the plate compression of the chart, the benchmarks), so that each key
reaches the engine the same way and none is lost on the way (relaxation, precision, the
integrator's tolerance). The keys come checked by the schema (:mod:`.checks`): nothing here
checks a value again, and no engine error is caught to be rewritten.
"""
from __future__ import annotations

import os
import sys
from pathlib import Path

import numpy as np

from tissue_sim_ros.engine.mesh.files import load_mesh, load_point_sets
from tissue_sim_ros.engine.mesh.selectors import node_mask
from tissue_sim_ros.engine.mesh.generators import box_axes, graded_box_axes, grid_elements, grid_mesh
from tissue_sim_ros.engine.model.material import Material, MeanRatioLaw, Viscosity
from tissue_sim_ros.engine.model.tensor_mass import TensorMassModel
from tissue_sim_ros.engine.scene.variation import DEPTH_SELECTORS, has_depth
from tissue_sim_ros.engine.needle.parameters import (FlexibleShaft, Friction, Membrane, NeedleGeometry,
                                                     RegionInteraction, TipShape)
from tissue_sim_ros.engine.solver.explicit import Simulation
from tissue_sim_ros.engine.solver.settle import settled_state
from tissue_sim_ros.engine.solver.supports import foundation, unrestrained_modes
from tissue_sim_ros.errors import SceneError

__all__ = ['build_gravity', 'build_material', 'build_mesh', 'build_supports', 'element_limit', 'build_model',
           'build_simulation', 'check_combinations', 'check_time_step', 'fixed_nodes', 'needle_geometry',
           'point_sets_of', 'physical_law', 'region_interaction', 'tip_shape', 'viscosity']


def check_combinations(spec: dict) -> None:
    """What no single key's check can see: keys that cannot go together, refused naming both."""
    integrator, model = spec['solver']['integrator'], spec['model']
    if integrator != 'explicit' and model['precision'] != 'float64':
        raise SceneError(f"solver.integrator = {integrator!r} needs model.precision = float64, got "
                         f"{model['precision']!r}: its Newton tangent differences forces 1e-8 of the body "
                         "size apart, below float32 arithmetic's resolution (1e-7)")
    for k, region in enumerate(spec['regions']):
        if region['depth_spread_m'] > 0 and not has_depth(region['select']):
            raise SceneError(f"regions[{k}].depth_spread_m = {region['depth_spread_m']!r} with "
                             f"regions[{k}].select = {region['select']!r}: a spread of depth needs a boundary "
                             f"with a depth ({', '.join(DEPTH_SELECTORS)})")
    if integrator != 'explicit' and spec['solver']['selective_mass_scaling'] != 1.0:
        raise SceneError(f"solver.selective_mass_scaling = {spec['solver']['selective_mass_scaling']!r} with "
                         f'solver.integrator = {integrator!r}: it raises the explicit step; the implicit '
                         'integrators are stable at any step (leave it 1)')
    if integrator != 'explicit' and model['relaxation']:
        raise SceneError(f'solver.integrator = {integrator!r} with model.relaxation: the implicit and '
                         'quasi-static integrators do not support relaxation yet (its internal variables '
                         "advance once a step); use integrator 'explicit' or no relaxation")


#: memory a tetrahedron takes in a running scene (the model's arrays, the solver's, the per-thread
#: force buffers), with a margin: 1.2 kB measured on the default scene's model at 288000
BYTES_PER_ELEMENT = 2000
#: a mesh this large is announced on stderr before it is built (it takes seconds)
ANNOUNCE_ELEMENTS = 200_000


def element_limit(spec: dict) -> tuple[int, str]:
    """(the largest mesh a scene may build, how it was set): ``mesh.max_elements``, or half this
    machine's memory at BYTES_PER_ELEMENT a tetrahedron."""
    if spec['max_elements'] is not None:
        return int(spec['max_elements']), f"mesh.max_elements = {spec['max_elements']:g}"
    try:
        memory = os.sysconf('SC_PAGE_SIZE') * os.sysconf('SC_PHYS_PAGES')
    except (ValueError, OSError, AttributeError):          # no sysconf: a small machine's bound
        memory = 8 << 30
    limit = int(0.5 * memory / BYTES_PER_ELEMENT)
    return limit, (f'mesh.max_elements = null: {limit:.3g} on this machine (half its {memory / 2**30:.0f} GiB '
                   f'at about {BYTES_PER_ELEMENT / 1e3:g} kB a tetrahedron)')


def _check_size(elements: int, spec: dict, what: str) -> None:
    limit, how = element_limit(spec)
    if elements > limit:
        raise SceneError(f'mesh: {what} makes about {elements:.3g} tetrahedra, more than {how}; check '
                         'the mesh keys (a size in mm written as metres?) or raise mesh.max_elements')
    if elements > ANNOUNCE_ELEMENTS:
        print(f'tissue_sim_ros: building a mesh of about {elements:.3g} tetrahedra ({what}; about '
              f'{elements * BYTES_PER_ELEMENT / 2**30:.1f} GiB once running)', file=sys.stderr, flush=True)


def build_mesh(spec: dict, base_dir) -> object:
    """The ``mesh`` section's TetMesh (before regions are assigned), its size checked against
    :func:`element_limit` before anything large is made."""
    if spec['generator'] == 'file':
        if not spec['file']:
            raise SceneError("mesh.file = '': expected a mesh file name with generator: file")
        path = Path(spec['file'])
        mesh = load_mesh(path if path.is_absolute() else Path(base_dir) / path)
        _check_size(mesh.n_elements, spec, f'mesh.file = {spec["file"]!r}')
        return mesh
    divisions = [int(round(d)) for d in spec['divisions']]
    if spec['generator'] == 'box':
        axes = box_axes(spec['size_m'], divisions, spec['origin_m'])
        what = f'mesh.divisions = {divisions}'
    else:
        axes = graded_box_axes(spec['size_m'], divisions, spec['origin_m'], focus=spec['focus_xy_m'],
                               focus_radius=spec['focus_radius_m'], growth=spec['growth'],
                               fine_size=spec['fine_size_m'], grade_z=spec['grade_z'])
        what = f"mesh.fine_size_m = {spec['fine_size_m']:g} and mesh.divisions = {divisions}"
    _check_size(grid_elements(axes), spec, what)
    return grid_mesh(axes)


def build_material(region: dict) -> Material:
    """A region's Material (its values checked by the schema)."""
    return Material(region['young_modulus_pa'], region['poisson_ratio'], region['density_kg_per_m3'])


def physical_law(spec: dict):
    """``model.physical``'s MeanRatioLaw, or None."""
    if spec['law'] == 'none':
        return None
    if spec['law'] == 'polynomial':
        return MeanRatioLaw.polynomial(spec['lambda_coefficients'], spec['mu_coefficients'])
    return MeanRatioLaw.exponential(spec['lambda_amplitude'], spec['lambda_rate'],
                                    spec['mu_amplitude'], spec['mu_rate'])


def viscosity(model: dict):
    """``model``'s Kelvin-Voigt Viscosity, or None when both coefficients are 0."""
    if model['viscosity_lambda_pa_s'] > 0 or model['viscosity_mu_pa_s'] > 0:
        return Viscosity(model['viscosity_lambda_pa_s'], model['viscosity_mu_pa_s'])
    return None


def build_model(mesh, materials, model: dict) -> TensorMassModel:
    """The TensorMassModel of ``mesh`` with ``materials`` (a Material, or {region: Material})
    and every key of the ``model`` section."""
    return TensorMassModel(mesh, materials, geometric=model['geometric'],
                           physical=physical_law(model['physical']), viscosity=viscosity(model),
                           nonlinearity_threshold=model['nonlinearity_threshold'],
                           inversion_safeguard=model['inversion_safeguard'],
                           relaxation=model['relaxation'], precision=model['precision'])


#: build_simulation's ``dt`` default: the section's ``time_step_s``
SCENE_STEP = 'scene'


def build_simulation(model, solver: dict, fixed=None, *, dt=SCENE_STEP, integrator=None) -> Simulation:
    """The Simulation of ``model`` with every key of the ``solver`` section; ``dt`` (None: the
    section's ``time_step_safety`` of this model's critical step) and ``integrator`` replace the
    section's step and integrator (a study's variants on another mesh)."""
    return Simulation(model, damping=solver['damping_per_s'], fixed=fixed,
                      dt=solver['time_step_s'] if dt is SCENE_STEP else dt,
                      time_step_safety=solver['time_step_safety'], mass_scaling=solver['mass_scaling'],
                      integrator=integrator or solver['integrator'],
                      newton_tolerance=solver['newton_tolerance'])


def fixed_nodes(mesh, faces, point_sets=None) -> np.ndarray:
    """Mask of the nodes ``boundary.fixed`` holds: on the named bounding-box faces, or selected
    (engine.mesh.selectors.node_mask; ``point_sets``: the mesh file's, for ``node_set``)."""
    x = mesh.rest_positions
    lo, hi = x.min(axis=0), x.max(axis=0)
    tol = 1e-9 * float(np.max(hi - lo))
    on = {'x_min': np.abs(x[:, 0] - lo[0]) <= tol, 'x_max': np.abs(x[:, 0] - hi[0]) <= tol,
          'y_min': np.abs(x[:, 1] - lo[1]) <= tol, 'y_max': np.abs(x[:, 1] - hi[1]) <= tol,
          'bottom': np.abs(x[:, 2] - lo[2]) <= tol, 'top': np.abs(x[:, 2] - hi[2]) <= tol}
    on['walls'] = on['x_min'] | on['x_max'] | on['y_min'] | on['y_max']
    mask = np.zeros(len(x), dtype=bool)
    for i, f in enumerate(faces):
        mask |= on[f] if isinstance(f, str) else node_mask(f, mesh, point_sets, f'boundary.fixed[{i}]')
    return mask


def point_sets_of(spec: dict, base_dir):
    """The mesh file's point data when a support selects a ``node_set`` (else None: not read)."""
    selects = list(spec['boundary']['fixed']) + [entry['select'] for entry in spec['boundary']['springs']]
    if not any(isinstance(f, dict) and 'node_set' in f for f in selects):
        return None
    if spec['mesh']['generator'] != 'file':
        raise SceneError("boundary: a node_set selector needs mesh.generator: file (the sets are the mesh file's "
                         'point data)')
    path = Path(spec['mesh']['file'])
    return load_point_sets(path if path.is_absolute() else Path(base_dir) / path)


def build_supports(simulation, mesh, boundary: dict, point_sets=None) -> np.ndarray:
    """Hold ``simulation``'s nodes as ``boundary`` says (fixed nodes and foundations), refused
    naming the key when they cannot stop rigid motion (engine.solver.supports); returns the
    mask of the fixed nodes."""
    held = fixed_nodes(mesh, boundary['fixed'], point_sets)
    n = mesh.n_nodes
    rows = np.full(n, -1, dtype=np.int64)
    total = np.zeros((n, 6))
    for i, entry in enumerate(boundary['springs']):
        selected = node_mask(entry['select'], mesh, point_sets, f'boundary.springs[{i}].select')
        nodes, stiffness = foundation(mesh.rest_positions, mesh.surface_triangles(), selected,
                                      entry['normal_n_per_m3'], entry['tangential_n_per_m3'])
        if len(nodes) == 0:
            raise SceneError(f'boundary.springs[{i}].select = {entry["select"]!r}: selects no surface triangle '
                             '(all three nodes of a surface triangle must be selected)')
        total[nodes] += stiffness
    supported = np.flatnonzero(np.abs(total).sum(axis=1) > 0)
    rows[supported] = np.arange(len(supported))
    loose = unrestrained_modes(mesh.rest_positions, held, rows, total[supported])
    if loose:
        count = int(held.sum())
        raise SceneError(f'boundary.fixed = {boundary["fixed"]!r} holds {count} node{"s" * (count != 1)}'
                         f'{" and boundary.springs " + str(len(boundary["springs"])) + " patches" if boundary["springs"] else ""}'
                         f': the tissue is free to move rigidly ({", ".join(loose)}); hold at least three nodes '
                         'not on one line, or add springs that stop it')
    simulation.fix(held)
    if len(supported):
        simulation.set_supports(rows, total[supported])
    return held


def build_gravity(simulation, solver: dict, key_text: str) -> dict | None:
    """Gravity (``solver.gravity_m_s2``) as body forces m_i g with the unscaled masses, and the
    tissue settled under it (engine.solver.settle, cached per scene); returns how it settled,
    None without gravity."""
    g = np.asarray(solver['gravity_m_s2'], dtype=float)
    if not g.any():
        return None
    masses = simulation.model.lumped_masses()
    simulation.set_body_forces(masses[:, None] * g[None, :])
    displacement, info = settled_state(simulation, key_text)
    simulation.set_initial_state(displacement)
    np.copyto(simulation.external_forces, simulation.body_forces)
    info['max_displacement_m'] = float(np.linalg.norm(displacement, axis=1).max())
    return info


def check_time_step(simulation, solver: dict) -> None:
    """A fixed time step above the estimated critical step diverges within steps: refused at
    load, naming both (an explicit run only; the implicit ones are stable at any step)."""
    dt = solver['time_step_s']
    if solver['integrator'] != 'explicit':
        return
    if dt is None and solver['time_step_safety'] > 1:
        raise SceneError(f"solver.time_step_safety = {solver['time_step_safety']!r}: expected at most "
                         f'1 (the step would be above the estimated critical step '
                         f'{simulation.critical_time_step():.4g} s)')
    if dt is not None and dt > simulation.critical_time_step():
        raise SceneError(
            f'solver.time_step_s = {dt!r}: above the estimated critical (largest stable) step '
            f'{simulation.critical_time_step():.4g} s of this mesh and material (mass scaling '
            f"{solver['mass_scaling']:g}); use at most that, raise solver.mass_scaling, or leave it "
            f'null for time_step_safety x the critical step')


def region_interaction(region: dict) -> RegionInteraction:
    """What a region brings to the needle: its membrane, cutting force and friction."""
    membrane = region['membrane']
    return RegionInteraction(
        name=region['name'],
        membrane=None if membrane['criterion'] == 'none' else Membrane(
            membrane['criterion'], membrane['rupture_force_n'], membrane['toughness_j_per_m2'],
            membrane['rate_exponent'], membrane['reference_speed_m_s']),
        cutting_force_n=region['cutting_force_n'],
        friction=Friction(**region['friction']))


def tip_shape(tip: dict) -> TipShape:
    """The needle's TipShape (its angles checked by the schema)."""
    return TipShape(tip['shape'], tip['half_angle_deg'], tip['bevel_angle_deg'], tip['bevel_orientation_deg'])


def needle_geometry(needle: dict, name: str = 'needle') -> NeedleGeometry:
    """A needle section's NeedleGeometry (``name``: its key path, for the errors): a flexible
    shaft's inner diameter must be below the outer one."""
    shaft = None
    if needle['flexible']:
        if not needle['inner_diameter_m'] < needle['diameter_m']:
            raise SceneError(f"{name}.inner_diameter_m = {needle['inner_diameter_m']!r}: expected less than "
                             f"{name}.diameter_m = {needle['diameter_m']!r} (the tube's outer diameter)")
        shaft = FlexibleShaft(needle['inner_diameter_m'], needle['young_modulus_pa'], needle['rod_segments'])
    return NeedleGeometry(needle['diameter_m'], needle['length_m'], needle['shaft_point_spacing_m'],
                          needle['max_jump_m'], tip_shape(needle['tip']), shaft)
