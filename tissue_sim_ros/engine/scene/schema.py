"""Every key a scene file may hold, with its default, kind and meaning, and their validation.

The one place scene keys are documented (``tissue-sim scene-keys`` prints :func:`describe_keys`).
Units are SI and every dimensional key says its unit in its name. Unknown keys are refused with
their dotted name; a bad value with its dotted path, the value and what was expected.
"""
import copy
import math
from dataclasses import dataclass
from typing import Callable

from tissue_sim_ros.engine.needle.pose import DEFAULT_MAX_JUMP_M
from tissue_sim_ros.engine.model.relaxation import PronySeries

__all__ = ['SCHEMA', 'SceneError', 'apply_schema', 'describe_keys']


class SceneError(ValueError):
    """A scene file or value the engine refuses; names the key and the value."""


@dataclass(frozen=True)
class MappingList:
    """Kind of a key holding a list of mappings (default: none): each entry is checked against
    the schema ``entry``, then the whole list by ``check(entries, dotted_name)``, which raises a
    ValueError naming what it refuses."""
    entry: dict
    check: Callable


def check_targets(entries, name):
    from tissue_sim_ros.engine.scene.targets import check_targets as check
    check(entries, name)


# -- the schema: key -> (default, kind, meaning) -----------------------------------------------
# kinds: 'float+' (> 0), 'float0' (>= 0), 'float', 'int+', 'bool', 'vec3', 'vec3+', 'quat',
# 'str', 'scaling' (a number >= 1 or 'auto'), a tuple of allowed strings, 'floats' (list of
# numbers), a MappingList, or a nested dict.
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
        'select': ('all', 'select', "'all', {below_z_m: z}, {above_z_m: z} (half-spaces under and over the "
                                   "plane z), {box_m: [[x,y,z], [x,y,z]]}, {sphere_m: [x, y, z, r]} or "
                                   "{tag: N} (element tag of a mesh file), in rest coordinates [m]; later "
                                   "regions override earlier ones. Its surface is the layer boundary the "
                                   "needle meets (where its tip's material point enters); an element's "
                                   "material is its centroid's region"),
        'young_modulus_pa': (5000.0, 'float+', "Young's modulus [Pa]"),
        'poisson_ratio': (0.45, 'float', 'Poisson ratio, in (-1, 0.5)'),
        'density_kg_per_m3': (1060.0, 'float+', 'density [kg/m^3]'),
        'membrane': {
            'criterion': ('none', ('none', 'force', 'energy'), 'puncture criterion of the region boundary'),
            'rupture_force_n': (1.0, 'float+', "criterion 'force': axial force at rupture [N]"),
            'toughness_j_per_m2': (1000.0, 'float+', "criterion 'energy': work since contact per needle "
                                                     "cross-section area at rupture [J/m^2]"),
            'rate_exponent': (0.0, 'float', "criterion 'force': n of the rupture force F0 (v / v0)^n at the "
                                            "needle's axial speed v (0: the same at every speed; negative: "
                                            'falls with speed)'),
            'reference_speed_m_s': (0.001, 'float+', "criterion 'force': v0 of the rate law [m/s]"),
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
            'insertion_constant_n': (0.0, 'float0', 'friction that does not scale with the inserted length, '
                                                    'insertion [N] (shared by the shaft points)'),
            'retraction_constant_n': (0.0, 'float0', 'the same while retracting (magnitude) [N]: a near-'
                                                     'constant pull on the way out'),
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
        'precision': ('float64', ('float64', 'float32'), "the element pass's constants and arithmetic "
                                                         '(float32: forces within 1e-6; explicit integrator only)'),
        'relaxation': ([], MappingList({
            'relative_modulus': (None, 'float+', 'g_i, the part of the shear modulus this term relaxes '
                                                 '(required; 0 < g_i, sum of all g_i < 1)'),
            'time_constant_s': (None, 'float+', 'tau_i, its relaxation time constant [s] (required)'),
        }, PronySeries), 'stress relaxation, a Prony series on the deviatoric stress: shear modulus '
                         'mu (1 - sum_i g_i (1 - exp(-t / tau_i))), the bulk modulus unrelaxed; a list '
                         'of terms, [] for none'),
        'auto': (False, 'bool', 'let tissue-sim recommend choose the model, threshold, mesh, mass scaling and '
                                'integrator within auto_tolerance (the keys above: the full model it starts '
                                'from); cached per scene; `model: auto` alone means this with the defaults'),
        'auto_tolerance': (0.05, 'float+', 'auto: the force NRMSE allowed against the converged solution'),
    },
    'targets': ([], MappingList({
        'name': (None, 'str', 'the name planners use (topics, diagnostics, CSV columns); required'),
        'position_m': (None, 'vec3', 'its position at rest [m], inside the mesh; required'),
    }, check_targets), 'named points carried by the tissue (a tumour, a fiducial): embedded in the mesh at '
                       'rest, they move with its deformation; [] for none'),
    'needles': ([], 'needles', 'several needles or probes in the same tissue: a list of mappings, each '
                               "with a unique 'name' and any needle.* keys that differ from the needle "
                               'section (which gives the rest): initial_position_m at least. [] (default): '
                               "the needle section is the one needle, named 'needle'"),
    'boundary': {
        'fixed': (['bottom', 'walls'], 'faces', 'bounding-box faces held fixed: bottom, top, walls, '
                                                'x_min, x_max, y_min, y_max'),
    },
    'solver': {
        'integrator': ('explicit', ('explicit', 'implicit', 'quasi_static'),
                       'explicit (symplectic Euler, dt below the critical step), implicit (backward Euler, '
                       'Newton with a matrix-free conjugate-gradient solve: any dt) or quasi_static '
                       '(equilibrium each step, no inertia)'),
        'newton_tolerance': (1e-6, 'float+', 'implicit and quasi_static: Newton stops at this residual '
                                             'relative to the forces acting (1e-6 moves the default '
                                             'insertion\'s force by 5e-6 of its range from 1e-8, for 26 % '
                                             'fewer element passes)'),
        'time_step_s': (None, 'float+', 'time step [s]; null: time_step_safety x the explicit critical step'),
        'time_step_safety': (0.8, 'float+', 'fraction of the critical step used when time_step_s is null'),
        'damping_per_s': (50.0, 'float0', 'mass-proportional damping rate [1/s]'),
        'mass_scaling': (1.0, 'scaling', 'factor on node masses for quasi-static runs (>= 1; every run '
                                         'prints its estimated inertia error); auto: the largest whose '
                                         "force NRMSE on the scene's insertion at design_speed_m_s, "
                                         'against 4x, is within inertia_error_bound (probed once, '
                                         'cached; analysis.mass_scaling_rule)'),
        'inertia_error_bound': (0.02, 'float+', 'mass_scaling auto: the force NRMSE the mass scaling may add'),
        'design_speed_m_s': (0.005, 'float+', 'mass_scaling auto: the needle speed it is chosen for [m/s] '
                                              '(tissue-sim insert sets its own)'),
    },
    'needle': {
        'diameter_m': (0.0024, 'float+', 'needle diameter [m]'),
        'length_m': (0.15, 'float+', 'needle length, base to tip [m]'),
        'initial_position_m': ([0.0, 0.0, 0.159], 'vec3', 'base position at start and reset [m]'),
        'initial_orientation_xyzw': ([1.0, 0.0, 0.0, 0.0], 'quat', 'base orientation (axis +z) at start'),
        'start_gap_m': (None, 'float0', 'tip distance above the tissue surface along the axis at start '
                                        'and reset [m]; null: initial_position_m as given, else that '
                                        'position moved along the axis to this gap'),
        'shaft_point_spacing_m': (0.001, 'float+', 'tissue points along the shaft, one per this advance [m]'),
        'max_jump_m': (DEFAULT_MAX_JUMP_M, 'float+', 'largest base or tip move accepted in one advance() call [m]'),
        'tip': {
            'shape': ('flat', ('flat', 'conical', 'bevel'), 'the tip: flat end (bonded at first contact), '
                                                          'cone or bevel (bonded point by point as the indentation '
                                                          'grows; after puncture the faces push the tissue aside)'),
            'half_angle_deg': (30.0, 'float+', 'conical: the cone half-angle [deg]'),
            'bevel_angle_deg': (20.0, 'float+', 'bevel: the angle between the bevel face and the axis [deg]'),
            'bevel_orientation_deg': (0.0, 'float', 'bevel: direction of the sharp point about the axis, from '
                                                    "the needle frame's +x [deg]; the lateral force points "
                                                    'that way'),
        },
    },
}
_FACES = ('bottom', 'top', 'walls', 'x_min', 'x_max', 'y_min', 'y_max')


def _numeric_string(value):
    """A string that is a plain decimal number (1e-5, 2.5E3) as that float, anything else as it
    is: YAML 1.1 reads an exponent without a dot as a string."""
    if isinstance(value, str) and value.isascii():
        try:
            return float(value)
        except ValueError:
            return value
    return value


def _check_value(name, value, kind):
    """Validate one value against its kind; return it normalised (floats, lists)."""
    def fail(expected):
        raise SceneError(f'{name} = {value!r}: expected {expected}')

    def number(v):
        v = _numeric_string(v)
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
    if kind == 'scaling':
        if value == 'auto':
            return value
        value = _numeric_string(value)
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not value >= 1:
            fail("a factor >= 1 or 'auto'")
        kind = 'float+'
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
    if kind == 'needles':
        if not isinstance(value, (list, tuple)):
            fail("a list of mappings, each with a 'name'")
        names = []
        for i, entry in enumerate(value):
            if not isinstance(entry, dict) or not isinstance(entry.get('name'), str) or not entry['name'].strip():
                raise SceneError(f'{name}[{i}] = {entry!r}: expected a mapping with a non-empty name')
            if entry['name'] in names or not entry['name'].replace('_', 'a').isalnum():
                raise SceneError(f"{name}[{i}].name = {entry['name']!r}: expected a unique name of letters, "
                                 'digits and _ (it names the topics needle/<name>/pose and /wrench)')
            names.append(entry['name'])
        return [dict(entry) for entry in value]
    if kind == 'faces':
        if not isinstance(value, (list, tuple)) or any(f not in _FACES for f in value):
            fail('a list of ' + ', '.join(_FACES))
        return list(value)
    if isinstance(kind, MappingList):
        if not isinstance(value, (list, tuple)):
            fail('a list of mappings')
        entries = [apply_schema(f'{name}[{i}]', entry, kind.entry) for i, entry in enumerate(value)]
        try:
            kind.check(entries, name)
        except ValueError as exc:
            raise SceneError(str(exc)) from None
        return entries
    if kind == 'select':
        if value == 'all':
            return value
        if isinstance(value, dict) and len(value) == 1:
            (key, v), = value.items()
            if key == 'tag' and isinstance(v, int) and not isinstance(v, bool):
                return value
            if key in ('above_z_m', 'below_z_m'):
                return {key: number(v)}
            if key == 'sphere_m':
                sphere = _check_value(f'{name}.sphere_m', v, 'floats')
                if len(sphere) != 4 or not sphere[3] > 0:
                    fail('{sphere_m: [x, y, z, r]} with r > 0')
                return {key: sphere}
            if key == 'box_m' and isinstance(v, (list, tuple)) and len(v) == 2:
                return {key: [_check_value(f'{name}.box_m', c, 'vec3') for c in v]}
        fail("'all', {tag: N}, {box_m: [[x,y,z],[x,y,z]]}, {sphere_m: [x,y,z,r]}, {above_z_m: z} or "
             "{below_z_m: z}")
    raise AssertionError(kind)


def apply_schema(name, data, schema):
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
            out[key] = apply_schema(dotted, data.get(key), spec)
        elif isinstance(spec, list):
            items = data.get(key, [{}])
            if not isinstance(items, list) or not items:
                raise SceneError(f'{dotted} = {items!r}: expected a non-empty list')
            out[key] = [apply_schema(f'{dotted}[{i}]', item, spec[0]) for i, item in enumerate(items)]
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
            if isinstance(spec[1], MappingList):
                lines += describe_keys(spec[1].entry, dotted + '[].')
    return lines
