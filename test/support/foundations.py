"""A block of linear tissue (Poisson ratio 0) under gravity on supports: the scenes of the
support tests, and the analytic settlement of a column on an elastic (Winkler) foundation."""
from tissue_sim_ros.engine.scene.scene import Scene

__all__ = ['E', 'G', 'K_N', 'K_T', 'ON_FOUNDATION', 'RHO', 'SIZE', 'block', 'column']

E, RHO, G = 5000.0, 1000.0, 9.81
SIZE = (0.04, 0.04, 0.02)
K_N, K_T = 2.0e5, 1.0e5


def block(boundary, model=None, regions=None, targets=(), divisions=(4, 4, 4), gravity=(0.0, 0.0, -G)):
    spec = {'mesh': {'generator': 'box', 'size_m': list(SIZE), 'origin_m': [0.0, 0.0, 0.0],
                     'divisions': list(divisions)},
            'regions': regions or [{'name': 'tissue', 'young_modulus_pa': E, 'poisson_ratio': 0.0,
                                    'density_kg_per_m3': RHO}],
            'model': model or {'geometric': False, 'inversion_safeguard': False},
            'boundary': boundary, 'solver': {'gravity_m_s2': list(gravity)},
            'targets': list(targets),
            'needle': {'initial_position_m': [0.02, 0.02, 0.2]}}
    return Scene(spec)


ON_FOUNDATION = {'fixed': [], 'springs': [{'select': {'below_z_m': 1e-9}, 'normal_n_per_m3': K_N,
                                           'tangential_n_per_m3': K_T}]}


def column(z):
    """Downward displacement of a column of height H on a Winkler foundation k_n under its own
    weight, Poisson ratio 0 (uniaxial stress): rho g H / k_n + rho g (H z - z^2 / 2) / E."""
    h = SIZE[2]
    return RHO * G * h / K_N + RHO * G * (h * z - z * z / 2.0) / E
