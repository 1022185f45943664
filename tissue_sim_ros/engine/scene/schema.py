"""Every key a scene file may hold, with its default, kind and meaning: the one place.

``tissue-sim scene-keys`` prints :func:`describe_keys`; ``--markdown`` writes docs/scenes.md
(:func:`keys_markdown`). The checks of each kind are :mod:`.checks`; units are SI and every
dimensional key says its unit in its name (:func:`~.checks.unit_of`).
"""
from tissue_sim_ros.engine.model.relaxation import PronySeries
from tissue_sim_ros.engine.needle.pose import DEFAULT_MAX_JUMP_M
from tissue_sim_ros.engine.scene.checks import MappingList, Range, apply_schema, unit_of

__all__ = ['SCHEMA', 'apply_schema', 'describe_keys', 'keys_markdown']


def check_targets(entries, name):
    from tissue_sim_ros.engine.scene.targets import check_targets as check
    check(entries, name)


def check_springs(entries, name):
    for i, entry in enumerate(entries):
        if entry['select'] is None:
            raise ValueError(f'{name}[{i}].select: required, the surface patch the foundation holds')
        if entry['normal_n_per_m3'] == 0.0 and entry['tangential_n_per_m3'] == 0.0:
            raise ValueError(f'{name}[{i}]: normal_n_per_m3 and tangential_n_per_m3 are both 0: the patch holds '
                             'nothing; give a stiffness per area')


# -- the schema: key -> (default, kind, meaning) -----------------------------------------------
# the kinds are those of .checks; a nested dict is a section, a list of one dict a list of them
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
        'max_elements': (None, 'float+', 'the largest mesh the scene may build, in tetrahedra, checked '
                                         'before it is built; null: half this machine\'s memory at about '
                                         '2 kB a tetrahedron'),
    },
    'regions': [{
        'name': ('tissue', 'str', 'region name (reported in puncture events)'),
        'select': ('all', 'select', "'all', {below_z_m: z}, {above_z_m: z} (half-spaces under and over the "
                                   "plane z), {half_space_m: [x, y, z, nx, ny, nz]} (the side of the plane "
                                   "through (x, y, z) that the normal n points away from), {box_m: [[x,y,z], "
                                   "[x,y,z]]}, {sphere_m: [x, y, z, r]} or {tag: N} (element tag of a mesh "
                                   "file: tissue-sim mesh tags the organ 1, its inclusions 2, 3, ...), in rest "
                                   "coordinates [m]; later "
                                   "regions override earlier ones. Its surface is the layer boundary the "
                                   "needle meets (where its tip's material point enters); an element's "
                                   "material is its centroid's region"),
        'young_modulus_pa': (5000.0, 'float+', "Young's modulus [Pa]"),
        'poisson_ratio': (0.45, Range(-1.0, 0.5), 'Poisson ratio'),
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
            'rupture_force_spread_n': (0.0, 'float0', "criterion 'force': standard deviation of the rupture force "
                                                      'between repeats [N]: a run with variation.seed k >= 1 draws '
                                                      'its rupture force from it (0: the same in every run)'),
        },
        'depth_spread_m': (0.0, 'float0', 'standard deviation of the depth of this layer\'s boundary between '
                                          'repeats [m]: a run with variation.seed k >= 1 moves the selector '
                                          'down by a drawn offset (a plane, box, sphere or half-space; 0: no offset)'),
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
        'position_m': (None, 'vec3', 'its position at rest [m], inside the mesh; this or region'),
        'region': (None, 'str', "a region's name: the target at the centroid of that region's elements "
                                '(a tumour tagged by tissue-sim mesh); this or position_m'),
    }, check_targets), 'named points carried by the tissue (a tumour, a fiducial): embedded in the mesh at '
                       'rest, they move with its deformation; [] for none'),
    'needles': ([], 'needles', 'several needles or probes in the same tissue: a list of mappings, each '
                               "with a unique 'name' and any needle.* keys that differ from the needle "
                               'section (which gives the rest): initial_position_m at least. [] (default): '
                               "the needle section is the one needle, named 'needle'"),
    'variation': {
        'seed': (0, 'int0', 'which run of a simulated study this is: 0, the nominal scene (no spread '
                            'drawn); k >= 1, the k-th draw of the regions\' rupture_force_spread_n and '
                            'depth_spread_m (engine.scene.variation)'),
    },
    'boundary': {
        'fixed': (['bottom', 'walls'], 'supports', 'nodes held fixed: bounding-box faces (bottom, top, walls, '
                                                   'x_min, x_max, y_min, y_max) and selectors: any region select '
                                                   '(the nodes in its volume or of its tagged elements), '
                                                   '{surface_near_m: [x, y, z, d]} (the surface nodes within d of '
                                                   'the point: a ligament) or {node_set: NAME} (the nodes a mesh '
                                                   "file's point data NAME marks non-zero); the supports must stop "
                                                   'rigid motion (with the springs), else the scene is refused'),
        'springs': ([], MappingList({
            'select': (None, 'support', "the surface patch held: a boundary.fixed selector; the surface "
                                        'triangles whose three nodes it selects (required)'),
            'normal_n_per_m3': (0.0, 'float0', 'foundation stiffness along the surface normal, per area '
                                               '(pressure per displacement) [N/m^3]'),
            'tangential_n_per_m3': (0.0, 'float0', 'foundation stiffness along the surface, per area [N/m^3]'),
        }, check_springs), 'elastic foundations (Winkler) holding surface patches, the way neighbouring '
                           'organs hold one: each surface node takes k A (n n^T normal + (I - n n^T) '
                           'tangential) of its share A of the patch; [] for none'),
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
        'gravity_m_s2': ([0.0, 0.0, 0.0], 'vec3', 'gravitational acceleration in the mesh frame [m/s^2] (e.g. '
                                                  '[0, 0, -9.81]); the tissue is settled under it (with its '
                                                  'supports, a static solve, cached per scene) before the needle '
                                                  'moves, and a reset returns there'),
        'mass_scaling': (1.0, 'scaling', 'factor on node masses for quasi-static runs (>= 1; every run '
                                         'prints its estimated inertia error); auto: the largest whose '
                                         "force NRMSE on the scene's insertion at design_speed_m_s, "
                                         'against 4x, is within inertia_error_bound (probed once, '
                                         'cached; analysis.charting.mass_scaling_rule)'),
        'selective_mass_scaling': (1.0, Range(1.0, None, low_closed=True),
                                   'explicit: raise the critical step at least this factor by adding mass only '
                                   'at the nodes of the elements whose own step is below it (a mesher\'s few '
                                   'smallest or flattest elements set the step of a whole organ); the added '
                                   'mass is printed with the inertia error, which counts it; 1: off'),
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
        'planned_travel_m': (None, 'float+', 'the insertion the scene is for: tip travel along the axis from '
                                             'the start pose [m] (tissue-sim insert\'s default travel; chart, '
                                             'recommend and the mass-scaling rule score this insertion); null: '
                                             "the commands' own defaults"),
        'shaft_point_spacing_m': (0.001, 'float+', 'tissue points along the shaft, one per this advance [m]'),
        'max_jump_m': (DEFAULT_MAX_JUMP_M, 'float+', 'largest base or tip move accepted in one advance() call [m]'),
        'flexible': (False, 'bool', 'the shaft as an elastic rod that the tissue and the tip bend (a bevel '
                                    'steers it); false: rigid and straight'),
        'inner_diameter_m': (0.0, 'float0', 'flexible: the tube\'s inner diameter [m] (diameter_m is the outer '
                                            'one; 0: a solid rod)'),
        'young_modulus_pa': (200e9, 'float+', "flexible: the shaft's Young's modulus [Pa] (steel 200 GPa, "
                                              'nitinol 50-75 GPa)'),
        'rod_segments': (60, 'int+', 'flexible: segments the rod is divided into, equal along its length'),
        'tip': {
            'shape': ('flat', ('flat', 'conical', 'bevel'), 'the tip: flat end (bonded at first contact), '
                                                          'cone or bevel (bonded point by point as the indentation '
                                                          'grows; after puncture the faces push the tissue aside)'),
            'half_angle_deg': (30.0, Range(0.0, 90.0), 'conical: the cone half-angle [deg]'),
            'bevel_angle_deg': (20.0, Range(0.0, 90.0), 'bevel: the angle between the bevel face and the axis [deg]'),
            'bevel_orientation_deg': (0.0, 'float', 'bevel: direction of the sharp point about the axis, from '
                                                    "the needle frame's +x [deg]; the lateral force points "
                                                    'that way'),
        },
    },
}
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


def _rows(schema, prefix=''):
    """(dotted key, default, kind, meaning) of every key, depth first."""
    for key, spec in schema.items():
        dotted = f'{prefix}{key}'
        if isinstance(spec, dict):
            yield from _rows(spec, dotted + '.')
        elif isinstance(spec, list):
            yield from _rows(spec[0], dotted + '[].')
        else:
            yield dotted, spec[0], spec[1], spec[2]
            if isinstance(spec[1], MappingList):
                yield from _rows(spec[1].entry, dotted + '[].')


def _kind_text(kind) -> str:
    if isinstance(kind, tuple):
        return ', '.join(kind)
    if isinstance(kind, Range):
        return kind.text().replace('a number in ', '')
    if isinstance(kind, MappingList):
        return 'list of mappings'
    return {'float+': '> 0', 'float0': '>= 0', 'int+': 'integer >= 1', 'int0': 'whole number >= 0', 'float': 'number',
            'vec3+': '3 numbers > 0',
            'vec3': '3 numbers', 'vec2': '2 numbers', 'quat': 'x, y, z, w', 'floats': 'numbers',
            'scaling': ">= 1 or auto", 'faces': 'box faces',
            'supports': 'box faces, selectors', 'support': 'a selector', 'select': 'a region shape',
            'needles': 'list of needles'}.get(kind, kind)


def keys_markdown() -> str:
    """docs/scenes.md: every scene key as a table row (key, default, unit, values, meaning),
    one table per top-level section."""
    lines = ['# Scene keys', '',
             'Generated by `tissue-sim scene-keys --markdown` from the schema '
             '(`tissue_sim_ros/engine/scene/schema.py`); a test fails when this page is stale. '
             'How a scene is put together: [scene-guide.md](scene-guide.md).', '',
             'A key path picks list entries by index or name (`regions[0]`, `regions[liver]`, '
             '`model.relaxation[0]`); `--set KEY=VALUE` and `calibrate --fit` take any of them. '
             'A number may carry another unit of its quantity as text (`young_modulus_pa: 22 kPa`).']
    section = None
    for dotted, default, kind, meaning in _rows(SCHEMA):
        top = dotted.split('.')[0].split('[')[0]
        if top != section:
            section = top
            lines += ['', f'## {section}', '', '| key | default | unit | values | meaning |', '|---|---|---|---|---|']
        unit = unit_of(dotted.rsplit('.', 1)[-1])
        shown = '[]' if isinstance(kind, MappingList) and default == [] else repr(default)
        lines.append(f'| `{dotted}` | `{shown}` | {unit} | {_kind_text(kind)} | {meaning.replace("|", "/")} |')
    return '\n'.join(lines) + '\n'
