"""A scene: YAML description -> mesh, regions, model, boundary conditions, solver and needle.

Every key a scene file may hold is in :data:`SCHEMA` below, with its default and meaning (the one
place they are documented; ``tissue-sim scene-keys`` prints them). Files are safe-loaded;
unknown keys are refused with their dotted name; units are SI and every dimensional key says its
unit in its name. ``config/liver_sample.yaml`` is the default scene.

The scene is the engine's whole-step API: ``advance(duration, position, orientation)`` moves the
needle base linearly (orientation by slerp) from its current pose to the given one over
``duration`` seconds, stepping the tissue with the fixed time step ``dt``.
"""
import copy
import math
import time
from pathlib import Path

import numpy as np
import yaml

from tissue_sim_ros.engine.material import Material, MeanRatioLaw, Viscosity
from tissue_sim_ros.engine.mesh import box_mesh, graded_box_mesh, load_mesh, make_mesh
from tissue_sim_ros.engine.model import TensorMassModel
from tissue_sim_ros.engine.needle import (Friction, Membrane, NeedleGeometry, NeedleTissue,
                                          RegionInteraction, slerp)
from tissue_sim_ros.engine.solver import Simulation


class SceneError(ValueError):
    """A scene file or value the engine refuses; names the key and the value."""


def default_scene_path():
    """The packaged default scene, config/liver_sample.yaml (source tree or installed share/)."""
    here = Path(__file__).resolve().parents[2] / 'config' / 'liver_sample.yaml'
    if here.exists():
        return here
    try:
        from ament_index_python.packages import get_package_share_directory
        return Path(get_package_share_directory('tissue_sim_ros')) / 'config' / 'liver_sample.yaml'
    except Exception:                    # no ament index: report the source-tree path
        return here


# -- the schema: key -> (default, kind, meaning) -----------------------------------------------
# kinds: 'float+' (> 0), 'float0' (>= 0), 'float', 'int+', 'bool', 'vec3', 'vec3+', 'quat',
# 'str', a tuple of allowed strings, 'floats' (list of numbers), or a nested dict.
SCHEMA = {
    'mesh': {
        'generator': ('graded_box', ('box', 'graded_box', 'file'), 'how the tetrahedral mesh is made'),
        'file': ('', 'str', 'mesh file meshio reads, relative to the scene file (generator: file)'),
        'size_m': ([0.06, 0.06, 0.04], 'vec3+', 'box extent x, y, z [m]'),
        'origin_m': ([-0.03, -0.03, -0.04], 'vec3', 'box corner with the smallest coordinates [m]'),
        'divisions': ([12, 12, 8], 'vec3+', 'cells along x, y, z (far field for graded_box)'),
        'fine_size_m': (0.0015, 'float+', 'graded_box: cell width near the focus [m]'),
        'focus_radius_m': (0.004, 'float0', 'graded_box: radius of the fine zone around the focus [m]'),
        'focus_xy_m': (None, 'vec2', 'graded_box: (x, y) the mesh is refined around; default the centre'),
        'growth': (1.3, 'float+', 'graded_box: width ratio of neighbouring cells (>= 1)'),
        'grade_z': (True, 'bool', 'graded_box: grade z toward the top face too'),
    },
    'regions': [{
        'name': ('tissue', 'str', 'region name (reported in puncture events)'),
        'select': ('all', 'select', "'all', {tag: N} (element tag of a mesh file), {box_m: [[x,y,z], "
                                   "[x,y,z]]}, {above_z_m: z} or {below_z_m: z}: elements whose centroid "
                                   "is inside; later regions override earlier ones"),
        'young_modulus_pa': (5000.0, 'float+', "Young's modulus [Pa]"),
        'poisson_ratio': (0.45, 'float', 'Poisson ratio, in (-1, 0.5)'),
        'density_kg_per_m3': (1060.0, 'float+', 'density [kg/m^3]'),
        'membrane': {
            'criterion': ('none', ('none', 'force', 'energy'), 'puncture criterion of the region boundary'),
            'rupture_force_n': (1.0, 'float+', "criterion 'force': axial force at rupture [N]"),
            'toughness_j_per_m2': (1000.0, 'float+', "criterion 'energy': work since contact per needle "
                                                     "cross-section area at rupture [J/m^2]"),
        },
        'cutting_force_n': (0.0, 'float0', 'cutting force at the tip while advancing inside [N]'),
        'friction': {
            'insertion_static_n_per_m': (0.0, 'float0', 'Karnopp static limit D per inserted length, insertion [N/m]'),
            'insertion_coulomb_n_per_m': (0.0, 'float0', 'Karnopp Coulomb C per length, insertion [N/m]'),
            'insertion_viscous_n_s_per_m2': (0.0, 'float0', 'Karnopp viscous b per length, insertion [N s/m^2]'),
            'retraction_static_n_per_m': (0.0, 'float0', 'static limit, retraction (magnitude) [N/m]'),
            'retraction_coulomb_n_per_m': (0.0, 'float0', 'Coulomb, retraction (magnitude) [N/m]'),
            'retraction_viscous_n_s_per_m2': (0.0, 'float0', 'viscous, retraction (magnitude) [N s/m^2]'),
            'stick_band_m_per_s': (5e-4, 'float+', 'relative speed band in which the tissue sticks [m/s]'),
        },
    }],
    'model': {
        'geometric': (True, 'bool', 'St Venant-Kirchhoff (large displacements) instead of linear'),
        'physical': {
            'law': ('none', ('none', 'polynomial', 'exponential'), 'mean-ratio Lame correction law'),
            'lambda_coefficients': ([], 'floats', 'polynomial: g_lambda(s) = c1 s + c2 s^2 + ...'),
            'mu_coefficients': ([], 'floats', 'polynomial: g_mu(s) coefficients'),
            'lambda_amplitude': (0.0, 'float0', 'exponential: g_lambda = A (exp(k s) - 1), A'),
            'lambda_rate': (0.0, 'float0', 'exponential: k for lambda'),
            'mu_amplitude': (0.0, 'float0', 'exponential: A for mu'),
            'mu_rate': (0.0, 'float0', 'exponential: k for mu'),
        },
        'viscosity_lambda_pa_s': (0.0, 'float0', 'Kelvin-Voigt lambda_v [Pa s] (0 and mu 0: none)'),
        'viscosity_mu_pa_s': (0.0, 'float0', 'Kelvin-Voigt mu_v [Pa s]'),
        'nonlinearity_threshold': (0.0, 'float0', 'elements deformed less than this take the linear force'),
        'inversion_safeguard': (True, 'bool', 'St Venant-Kirchhoff safeguard for near-inverted elements'),
    },
    'boundary': {
        'fixed': (['bottom', 'walls'], 'faces', 'bounding-box faces held fixed: bottom, top, walls, '
                                                'x_min, x_max, y_min, y_max'),
    },
    'solver': {
        'time_step_s': (None, 'float+', 'explicit time step [s]; null: time_step_safety x critical step'),
        'time_step_safety': (0.8, 'float+', 'fraction of the critical step used when time_step_s is null'),
        'damping_per_s': (50.0, 'float0', 'mass-proportional damping rate [1/s]'),
        'mass_scaling': (1.0, 'float+', 'factor on node masses for quasi-static runs (>= 1)'),
    },
    'needle': {
        'diameter_m': (0.0024, 'float+', 'needle diameter [m]'),
        'length_m': (0.15, 'float+', 'needle length, base to tip [m]'),
        'initial_position_m': ([0.0, 0.0, 0.159], 'vec3', 'base position at start and reset [m]'),
        'initial_orientation_xyzw': ([1.0, 0.0, 0.0, 0.0], 'quat', 'base orientation (axis +z) at start'),
        'shaft_point_spacing_m': (0.001, 'float+', 'tissue points along the shaft, one per this advance [m]'),
        'max_jump_m': (0.005, 'float+', 'largest base or tip move accepted in one advance() call [m]'),
    },
}
_FACES = ('bottom', 'top', 'walls', 'x_min', 'x_max', 'y_min', 'y_max')


def _check_value(name, value, kind):
    """Validate one value against its kind; return it normalised (floats, lists)."""
    def fail(expected):
        raise SceneError(f'{name} = {value!r}: expected {expected}')

    def number(v):
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            fail('a finite number')
        return float(v)

    if isinstance(kind, tuple):
        if value not in kind:
            fail('one of ' + ', '.join(kind))
        return value
    if kind == 'str':
        if not isinstance(value, str):
            fail('a string')
        return value
    if kind == 'bool':
        if not isinstance(value, bool):
            fail('true or false')
        return value
    if kind in ('float', 'float+', 'float0'):
        v = number(value)
        if kind == 'float+' and not v > 0:
            fail('a number > 0')
        if kind == 'float0' and not v >= 0:
            fail('a number >= 0')
        return v
    if kind in ('vec3', 'vec3+', 'vec2', 'quat', 'floats'):
        if not isinstance(value, (list, tuple)):
            fail('a list of numbers')
        v = [number(x) for x in value]
        size = {'vec3': 3, 'vec3+': 3, 'vec2': 2, 'quat': 4}.get(kind)
        if size is not None and len(v) != size:
            fail(f'{size} numbers')
        if kind == 'vec3+' and min(v) <= 0:
            fail('3 numbers > 0')
        return v
    if kind == 'faces':
        if not isinstance(value, (list, tuple)) or any(f not in _FACES for f in value):
            fail('a list of ' + ', '.join(_FACES))
        return list(value)
    if kind == 'select':
        if value == 'all':
            return value
        if isinstance(value, dict) and len(value) == 1:
            (key, v), = value.items()
            if key == 'tag' and isinstance(v, int) and not isinstance(v, bool):
                return value
            if key in ('above_z_m', 'below_z_m'):
                return {key: number(v)}
            if key == 'box_m' and isinstance(v, (list, tuple)) and len(v) == 2:
                return {key: [_check_value(f'{name}.box_m', c, 'vec3') for c in v]}
        fail("'all', {tag: N}, {box_m: [[x,y,z],[x,y,z]]}, {above_z_m: z} or {below_z_m: z}")
    raise AssertionError(kind)


def _apply_schema(name, data, schema):
    """Fill defaults and validate ``data`` against ``schema``; unknown keys refused by name."""
    if data is None:
        data = {}
    if not isinstance(data, dict):
        raise SceneError(f'{name or "scene"} = {data!r}: expected a mapping of keys')
    unknown = sorted(set(data) - set(schema))
    if unknown:
        where = f'{name}.' if name else ''
        raise SceneError(f'unknown scene key {where}{unknown[0]!s}; known keys here: {", ".join(schema)}')
    out = {}
    for key, spec in schema.items():
        dotted = f'{name}.{key}' if name else key
        if isinstance(spec, dict):
            out[key] = _apply_schema(dotted, data.get(key), spec)
        elif isinstance(spec, list):
            items = data.get(key, [{}])
            if not isinstance(items, list) or not items:
                raise SceneError(f'{dotted} = {items!r}: expected a non-empty list')
            out[key] = [_apply_schema(f'{dotted}[{i}]', item, spec[0]) for i, item in enumerate(items)]
        else:
            default, kind, _ = spec
            value = data.get(key, copy.deepcopy(default))
            out[key] = None if value is None and default is None else _check_value(dotted, value, kind)
    return out


def describe_keys(schema=SCHEMA, prefix=''):
    """Every scene key with its default and meaning, one per line (``tissue-sim scene-keys``)."""
    lines = []
    for key, spec in schema.items():
        dotted = f'{prefix}{key}'
        if isinstance(spec, dict):
            lines += describe_keys(spec, dotted + '.')
        elif isinstance(spec, list):
            lines.append(f'{dotted}: a list, one entry per region, each with:')
            lines += describe_keys(spec[0], dotted + '[].')
        else:
            lines.append(f'{dotted} (default {spec[0]!r}): {spec[2]}')
    return lines


# -- building ---------------------------------------------------------------------------------
def _build_mesh(spec, base_dir):
    if spec['generator'] == 'file':
        if not spec['file']:
            raise SceneError("mesh.file = '': expected a mesh file name with generator: file")
        path = Path(spec['file'])
        return load_mesh(path if path.is_absolute() else base_dir / path)
    divisions = [int(round(d)) for d in spec['divisions']]
    if spec['generator'] == 'box':
        return box_mesh(spec['size_m'], divisions, spec['origin_m'])
    return graded_box_mesh(spec['size_m'], divisions, spec['origin_m'], focus=spec['focus_xy_m'],
                           focus_radius=spec['focus_radius_m'], growth=spec['growth'],
                           fine_size=spec['fine_size_m'], grade_z=spec['grade_z'])


def _element_regions(mesh, regions):
    centroids = mesh.rest_positions[mesh.tetrahedra].mean(axis=1)
    index = np.full(mesh.n_elements, -1)
    for k, region in enumerate(regions):
        select = region['select']
        if select == 'all':
            inside = np.ones(mesh.n_elements, dtype=bool)
        elif 'tag' in select:
            inside = mesh.element_tags == select['tag']
        elif 'box_m' in select:
            lo, hi = np.array(select['box_m'][0]), np.array(select['box_m'][1])
            inside = np.all((centroids >= lo) & (centroids <= hi), axis=1)
        elif 'above_z_m' in select:
            inside = centroids[:, 2] >= select['above_z_m']
        else:
            inside = centroids[:, 2] <= select['below_z_m']
        index[inside] = k
    if np.any(index < 0):
        raise SceneError(f'regions: {int(np.sum(index < 0))} elements (first {int(np.argmax(index < 0))}) '
                         f'belong to no region; add a region with select: all first')
    return index


def _fixed_nodes(mesh, faces):
    x = mesh.rest_positions
    lo, hi = x.min(axis=0), x.max(axis=0)
    tol = 1e-9 * float(np.max(hi - lo))
    on = {'x_min': np.abs(x[:, 0] - lo[0]) <= tol, 'x_max': np.abs(x[:, 0] - hi[0]) <= tol,
          'y_min': np.abs(x[:, 1] - lo[1]) <= tol, 'y_max': np.abs(x[:, 1] - hi[1]) <= tol,
          'bottom': np.abs(x[:, 2] - lo[2]) <= tol, 'top': np.abs(x[:, 2] - hi[2]) <= tol}
    on['walls'] = on['x_min'] | on['x_max'] | on['y_min'] | on['y_max']
    mask = np.zeros(len(x), dtype=bool)
    for f in faces:
        mask |= on[f]
    return mask


def _physical_law(spec):
    if spec['law'] == 'none':
        return None
    if spec['law'] == 'polynomial':
        return MeanRatioLaw.polynomial(spec['lambda_coefficients'], spec['mu_coefficients'])
    return MeanRatioLaw.exponential(spec['lambda_amplitude'], spec['lambda_rate'],
                                    spec['mu_amplitude'], spec['mu_rate'])


def _region_interaction(region):
    membrane = region['membrane']
    return RegionInteraction(
        name=region['name'],
        membrane=None if membrane['criterion'] == 'none' else Membrane(
            membrane['criterion'], membrane['rupture_force_n'], membrane['toughness_j_per_m2']),
        cutting_force_n=region['cutting_force_n'],
        friction=Friction(**region['friction']))


class Scene:
    """A ready-to-run needle insertion scene (see the module docstring)."""

    def __init__(self, spec, text='', base_dir='.', mesh_frame_id='world'):
        self.spec = _apply_schema('', spec, SCHEMA)
        self.text = text
        self.mesh_frame_id = mesh_frame_id
        s = self.spec
        try:
            raw_mesh = _build_mesh(s['mesh'], Path(base_dir))
            element_region = _element_regions(raw_mesh, s['regions'])
            self.mesh = make_mesh(raw_mesh.rest_positions, raw_mesh.tetrahedra, element_region)
            materials = {k: Material(r['young_modulus_pa'], r['poisson_ratio'], r['density_kg_per_m3'])
                         for k, r in enumerate(s['regions']) if np.any(element_region == k)}
            m = s['model']
            viscosity = None
            if m['viscosity_lambda_pa_s'] > 0 or m['viscosity_mu_pa_s'] > 0:
                viscosity = Viscosity(m['viscosity_lambda_pa_s'], m['viscosity_mu_pa_s'])
            self.model = TensorMassModel(self.mesh, materials, geometric=m['geometric'],
                                         physical=_physical_law(m['physical']), viscosity=viscosity,
                                         nonlinearity_threshold=m['nonlinearity_threshold'],
                                         inversion_safeguard=m['inversion_safeguard'])
            sol = s['solver']
            if sol['mass_scaling'] < 1:
                raise SceneError(f"solver.mass_scaling = {sol['mass_scaling']!r}: expected >= 1")
            self.simulation = Simulation(self.model, damping=sol['damping_per_s'],
                                         fixed=_fixed_nodes(self.mesh, s['boundary']['fixed']),
                                         dt=sol['time_step_s'], time_step_safety=sol['time_step_safety'],
                                         mass_scaling=sol['mass_scaling'])
            n = s['needle']
            geometry = NeedleGeometry(n['diameter_m'], n['length_m'], n['shaft_point_spacing_m'],
                                      n['max_jump_m'])
            self.needle = NeedleTissue(self.simulation, element_region,
                                       [_region_interaction(r) for r in s['regions']], geometry,
                                       n['initial_position_m'], n['initial_orientation_xyzw'])
        except SceneError:
            raise
        except ValueError as exc:        # MaterialError, MeshError, NeedleInputError...
            raise SceneError(str(exc)) from exc
        self._target_time = 0.0
        self.element_region = element_region
        self.region_names = [r['name'] for r in s['regions']]
        from tissue_sim_ros.engine.warm_up import warm_up
        warm_up()

    @classmethod
    def from_file(cls, path=None, **overrides):
        """Load a scene YAML (default: the packaged liver sample); ``overrides`` replace top-level
        sections key by key, e.g. model={'viscosity_mu_pa_s': 0.0}."""
        path = Path(path) if path is not None else default_scene_path()
        try:
            text = path.read_text()
        except OSError as exc:
            raise SceneError(f'scene_file = {str(path)!r}: {exc.strerror}') from exc
        try:
            spec = yaml.safe_load(text)
        except yaml.YAMLError as exc:
            raise SceneError(f'scene_file = {str(path)!r}: not valid YAML ({exc})') from exc
        spec = merge(spec or {}, overrides)
        return cls(spec, text=text, base_dir=path.parent)

    # -- stepping ---------------------------------------------------------------------------------
    @property
    def dt(self):
        return self.simulation.dt

    @property
    def time(self):
        return self.simulation.time

    def advance(self, duration, position, orientation, deadline=None, max_steps=None):
        """Move the needle to the given base pose over ``duration`` [s]; returns the substeps run.

        Runs the whole steps that end by the running target time (the sum of all durations since
        reset, ``target_time``); the needle ends on its way to the pose, less than one step before
        it, and reaches it in the next call. ``deadline`` (a time.perf_counter() value): no step
        starts that would, by the last step's wall time, end past it; the steps left are run by
        the next call (duration 0 runs just those), so a real-time caller keeps its slots.
        ``max_steps`` stops the same way after that many steps (a replay of a run that a deadline
        stopped).
        Raises NeedleInputError (before any state changes) for a bad pose, SimulationDiverged if
        the tissue diverges.
        """
        if not (isinstance(duration, (int, float)) and math.isfinite(duration) and duration >= 0):
            raise SceneError(f'duration = {duration!r}: expected a finite time >= 0 s')
        needle, sim = self.needle, self.simulation
        position, orientation = needle.check_pose(position, orientation)
        start_p, start_q = needle.position.copy(), needle.orientation.copy()
        # whole steps toward a running target time, so the remainders of successive calls add up
        # instead of being dropped (20 ms calls with a 1.7 ms step would otherwise run 20.6 ms).
        # No step ends past the target: a step that did would hold the needle at the target for
        # part of it, a velocity dip whose inertial force the bonded contact reports at exactly
        # the step a caller samples (-0.06 N at 10 mm/s, 25x mass scaling, every third tick).
        # The needle stays on its segment at the pose for the simulation's time, and the next
        # call goes on from there at the same speed.
        start_t, end_t = sim.time, self._target_time + duration
        self._target_time = end_t
        steps = 0
        step_wall = 0.0
        while sim.time + sim.dt <= end_t + 1e-9 * sim.dt:
            if max_steps is not None and steps >= max_steps:
                return steps
            if deadline is not None:
                now = time.perf_counter()
                if now + step_wall > deadline:
                    return steps
            s = min(1.0, (sim.time + sim.dt - start_t) / (end_t - start_t))
            needle.set_pose(start_p + s * (position - start_p), slerp(start_q, orientation, s))
            sim.step(1)
            needle.after_step(sim.dt)
            steps += 1
            if deadline is not None:
                step_wall = time.perf_counter() - now
        if duration == 0 and steps == 0:
            needle.set_pose(position, orientation)
            needle.set_pose(position, orientation)   # no step: no velocity from a pose change
        return steps

    @property
    def target_time(self):
        """The running target time [s]: the sum of the durations asked of ``advance`` since reset
        (the simulation is less than one step short of it, or more where a deadline stopped it)."""
        return self._target_time

    def reset(self):
        """Rest state, needle at its initial pose, time 0."""
        self.simulation.reset()
        self.simulation.external_forces[:] = 0.0
        self.needle.reset()
        self._target_time = 0.0

    # -- state ----------------------------------------------------------------------------------
    def reaction_wrench(self, frame='world'):
        return self.needle.reaction_wrench(frame)

    @property
    def phase(self):
        return self.needle.phase

    @property
    def tip_depth(self):
        return self.needle.tip_depth()

    @property
    def needle_pose(self):
        return self.needle.position.copy(), self.needle.orientation.copy()

    @property
    def rest_positions(self):
        return self.mesh.rest_positions

    @property
    def displacement(self):
        return self.simulation.displacement

    def surface_triangles(self):
        return self.model.mesh.surface_triangles() if self.model.topology_version == 0 else \
            _current_surface(self.model)

    @property
    def topology_version(self):
        return self.model.topology_version

    @property
    def puncture_events(self):
        return self.needle.puncture_events


def _current_surface(model):
    from tissue_sim_ros.engine.mesh import surface_triangles
    return surface_triangles(model.tetrahedra, model.mesh.rest_positions)


def merge(base, overrides):
    """Recursive dict merge: ``overrides`` wins key by key (lists are replaced whole)."""
    out = dict(base)
    for key, value in overrides.items():
        if isinstance(value, dict) and isinstance(out.get(key), dict):
            out[key] = merge(out[key], value)
        else:
            out[key] = value
    return out
