"""A flexible needle's figures, printed::

    tissue-sim bench steering [--parts air tissue phantom flip cost] [--depth-mm 80]
                              [--speed-mm-s 5] [--jobs N] [--out DIR]

- ``air``: the rod alone, clamped at its base: a small tip load against F L^3 / (3 E I), and the
  large-deflection elastica (scipy's ``solve_bvp`` on theta'' = -(F / EI) cos theta) at tip
  rotations of about 30, 45 and 60 degrees;
- ``tissue``: a 20 G nitinol and an 18 G steel needle inserted ``--depth-mm`` into the default
  tissue (config/liver_sample.yaml, its block made 100 mm deep), bevel toward +x, bevel turned 180
  degrees, and a conical tip: the tip's deflection from the base's axis, the radius of the circle
  tangent to the axis at the entry through the last 60 % of its path and the spread of the radii
  through its three thirds; the bevel's own bend is half the difference of the two bevels' (the
  mesh's bias cancels); the conical tip's deflection is the mesh's noise;
- ``phantom``: a short insertion in a small block whose cutting force (0.5 N) lets the bevel push
  harder: the radius of the bevel's own bend for rods of three bending stiffnesses and two
  tissues (the stiffer with a proportionally higher cutting force, as a stiffer gel is also
  tougher), the directions of Misra et al. (2010);
- ``flip``: the phantom's nitinol needle turned 180 degrees about its axis half-way: the path
  bends one way, then the other (an S);
- ``cost``: the default scene's step with the rod against without it, in this process, paired
  (rigid and flexible insertions alternated, three each), microseconds per substep inside the
  tissue.

Each part's runs go over ``--jobs`` processes (analysis.jobs). ``--out DIR`` keeps the figures
as ``steering.json``.
"""
from __future__ import annotations

import json
import math
import time
from pathlib import Path

import numpy as np

__all__ = ['NEEDLES', 'PARTS', 'air_figures', 'main']

PARTS = ('air', 'tissue', 'phantom', 'flip', 'cost')
#: (outer diameter [m], inner diameter [m], Young's modulus [Pa]) of the needles the figures use
NEEDLES = {'20 G nitinol': (0.000908, 0.000603, 60e9), '18 G steel': (0.00127, 0.000838, 200e9),
           '20 G steel': (0.000908, 0.000603, 200e9), '20 G nitinol 30 GPa': (0.000908, 0.000603, 30e9)}
#: the default tissue in a block deep enough for an 80 mm insertion (the default mesh's cells)
DEEP_BLOCK = ['mesh.size_m=[0.06,0.06,0.1]', 'mesh.origin_m=[-0.03,-0.03,-0.1]', 'mesh.divisions=[10,10,20]',
              'mesh.focus_radius_m=0.004']
#: a small block (the default tissue's material, coarse far away) with a cutting force that lets
#: the bevel push harder: the phantom of the trends and the flip
PHANTOM = ['mesh.size_m=[0.024,0.024,0.045]', 'mesh.origin_m=[-0.012,-0.012,-0.045]', 'mesh.divisions=[4,4,7]',
           'regions[0].membrane.rupture_force_n=0.5', 'regions[0].cutting_force_n=0.5', 'needle.length_m=0.07',
           'needle.initial_position_m=[0,0,0.072]', 'needle.rod_segments=35']


def needle_sets(name: str, tip: str = 'bevel', orientation_deg: float = 0.0) -> list[str]:
    outer, inner, modulus = NEEDLES[name]
    return ['needle.flexible=true', f'needle.diameter_m={outer}', f'needle.inner_diameter_m={inner}',
            f'needle.young_modulus_pa={modulus}', f'needle.tip.shape={tip}',
            f'needle.tip.bevel_orientation_deg={orientation_deg}']


# -- in air -------------------------------------------------------------------------------------
def elastica_tip(load_ratio: float, length: float = 1.0):
    """(tip x, tip z, tip rotation [rad]) of a clamped elastica of ``length`` under a dead load
    perpendicular to its clamp (load_ratio = F L^2 / EI): theta'' = -(F / EI) cos theta,
    theta(0) = 0, theta'(L) = 0 (scipy's solve_bvp), x and z integrated along it."""
    from scipy.integrate import solve_bvp
    s = np.linspace(0.0, length, 201)
    k = load_ratio / length ** 2
    sol = solve_bvp(lambda _, y: np.vstack([y[1], -k * np.cos(y[0])]), lambda a, b: np.array([a[0], b[1]]), s,
                    np.vstack([0.5 * k * s * (2 * length - s), k * (length - s)]), tol=1e-10, max_nodes=100000)
    fine = np.linspace(0.0, length, 20001)
    theta = sol.sol(fine)[0]
    return (float(np.trapezoid(np.sin(theta), fine)), float(np.trapezoid(np.cos(theta), fine)), float(theta[-1]))


def rod_tip(load_ratio: float, segments: int, length: float = 0.08, needle: str = '20 G nitinol'):
    """(tip x, tip z, tip rotation) of the discrete rod (engine.needle.rod) of ``needle``'s tube,
    clamped along +z at the origin, under a tip load F = load_ratio EI / L^2 along +x."""
    from tissue_sim_ros.engine.needle.rod import RodSection, static_solve, straight_nodes
    outer, inner, modulus = NEEDLES[needle]
    section = RodSection(outer, inner, modulus)
    ei, ea = section.bending_stiffness_nm2, section.axial_stiffness_n
    nodes = straight_nodes([0.0, 0.0, 0.0], [0.0, 0.0, 1.0], length, segments)
    loads = np.zeros_like(nodes)
    loads[-1, 0] = load_ratio * ei / length ** 2
    static_solve(nodes, length / segments, ei, ea, np.array([0.0, 0.0, 1.0]), loads, 1, 1e-10 * loads[-1, 0], 200)
    last = nodes[-1] - nodes[-2]
    return float(nodes[-1, 0]), float(nodes[-1, 2]), float(math.atan2(last[0], last[2])), ei


def air_figures(segments: int = 60) -> dict:
    """The in-air checks (module docstring), as relative errors."""
    x, _, _, ei = rod_tip(1e-3, segments)
    small = {'load_n': 1e-3 * ei / 0.08 ** 2, 'deflection_m': x, 'linear_m': 1e-3 * 0.08 / 3,
             'error': x / (1e-3 * 0.08 / 3) - 1.0}
    large = []
    for ratio in (1.2, 2.0, 4.0):
        ex, ez, angle = elastica_tip(ratio, 0.08)
        rx, rz, rod_angle, _ = rod_tip(ratio, segments)
        large.append({'load_ratio': ratio, 'tip_rotation_deg': math.degrees(angle),
                      'rod_tip_rotation_deg': math.degrees(rod_angle), 'x_error': rx / ex - 1.0,
                      'z_error': rz / ez - 1.0})
    return {'segments': segments, 'small_load': small, 'elastica': large}


# -- in the tissue ------------------------------------------------------------------------------
def _run(job):
    """One insertion (a job of analysis.jobs): (label, scene sets, travel below the surface [m],
    speed [m/s], roll at [m below the surface] or None)."""
    from tissue_sim_ros.analysis.steering import insert_path
    from tissue_sim_ros.engine.scene.scene import Scene
    label, sets, depth, speed, roll_at = job
    scene = Scene.from_file(sets=sets)
    gap = scene.start_gap_m
    point = scene.needle.rotation[:, 0].copy()         # the bevel's point at 0 degrees, before any roll
    path = insert_path(scene, gap + depth, speed, roll_at_m=None if roll_at is None else gap + roll_at,
                       roll_over_m=max(0.001, 2.5 * speed * 0.02))
    return label, path, point


def _bend(path, direction):
    from tissue_sim_ros.analysis.steering import path_curvature
    return path_curvature(path, direction=direction)


def _own(paths):
    """The bevel's own bend: half the difference of the 0 and 180 degree paths, as a TipPath."""
    from tissue_sim_ros.analysis.steering import TipPath
    a, b = paths
    inside = a.inside() & b.inside()
    half = 0.5 * (a.tip - b.tip)
    half -= (half @ a.axis)[:, None] * a.axis
    along = (0.5 * (a.tip + b.tip) - a.start) @ a.axis
    tip = a.start + along[:, None] * a.axis + half
    return TipPath(a.travel[inside], tip[inside], np.zeros(int(inside.sum())), ['inserted'] * int(inside.sum()),
                   a.axis, a.start, a.force[inside])


def tissue_figures(depth_m: float, speed_m_s: float, jobs: int | None) -> list[dict]:
    from tissue_sim_ros.analysis.jobs import run_jobs
    runs = [(f'{needle}|{tip}|{deg}', DEEP_BLOCK + needle_sets(needle, tip, deg), depth_m, speed_m_s, None)
            for needle in ('20 G nitinol', '18 G steel') for tip, deg in (('bevel', 0.0), ('bevel', 180.0),
                                                                          ('conical', 0.0))]
    done = {label: (path, x) for label, path, x in run_jobs(_run, runs, workers=jobs, label='insertions')}
    figures = []
    for needle in ('20 G nitinol', '18 G steel'):
        bevel, flipped, cone = (done[f'{needle}|{t}|{d}'] for t, d in (('bevel', 0.0), ('bevel', 180.0),
                                                                       ('conical', 0.0)))
        point = bevel[1]                       # the bevel's point: the needle frame's +x (world)
        bend, own = _bend(bevel[0], point), _bend(_own((bevel[0], flipped[0])), point)
        figures.append({
            'needle': needle, 'depth_mm': depth_m * 1e3,
            'tip_deflection_mm': float(bevel[0].deflection[-1] * 1e3),
            'toward_bevel_mm': float(bend.lateral[-1] * 1e3),
            'radius_m': bend.radius_m, 'spread': bend.spread,
            'bevel_180_toward_bevel_0_mm': float(_bend(flipped[0], point).lateral[-1] * 1e3),
            'own_bend_mm': float(own.lateral[-1] * 1e3), 'own_radius_m': own.radius_m, 'own_spread': own.spread,
            'conical_deflection_mm': float(cone[0].deflection[-1] * 1e3),
            'wall_s': float(bevel[0].wall_s)})
    return figures


def phantom_figures(speed_m_s: float, jobs: int | None, depth_m: float = 0.022) -> list[dict]:
    from tissue_sim_ros.analysis.jobs import run_jobs
    from tissue_sim_ros.engine.needle.rod import RodSection
    cases = [('20 G nitinol 30 GPa', []), ('20 G nitinol', []), ('20 G steel', []),
             ('20 G nitinol', ['regions[0].young_modulus_pa=60000', 'regions[0].cutting_force_n=1.33'])]
    runs = [(f'{k}|{deg}', PHANTOM + needle_sets(needle, 'bevel', deg) + tissue, depth_m, speed_m_s, None)
            for k, (needle, tissue) in enumerate(cases) for deg in (0.0, 180.0)]
    done = {label: (path, x) for label, path, x in run_jobs(_run, runs, workers=jobs, label='phantom')}
    figures = []
    for k, (needle, tissue) in enumerate(cases):
        a, b = done[f'{k}|0.0'], done[f'{k}|180.0']
        own = _bend(_own((a[0], b[0])), a[1])
        figures.append({'needle': needle, 'bending_stiffness_nm2': RodSection(*NEEDLES[needle]).bending_stiffness_nm2,
                        'tissue': 'E 60 kPa, cutting 1.33 N' if tissue else 'E 22.6 kPa, cutting 0.5 N',
                        'own_bend_mm': float(own.lateral[-1] * 1e3), 'own_radius_m': own.radius_m,
                        'own_spread': own.spread})
    return figures


def flip_figures(speed_m_s: float, depth_m: float = 0.03) -> dict:
    label, path, point = _run(('flip', PHANTOM + needle_sets('20 G nitinol'), depth_m, speed_m_s, 0.5 * depth_m))
    bend = _bend(path, point)
    half = bend.along <= 0.5 * bend.along[-1]
    first = np.polyfit(bend.along[half], bend.lateral[half], 2)[0] * 2.0
    second = np.polyfit(bend.along[~half], bend.lateral[~half], 2)[0] * 2.0
    k = int(np.argmax(bend.lateral))
    return {'depth_mm': depth_m * 1e3, 'flip_at_mm': 0.5 * depth_m * 1e3, 'curvature_first_half_per_m': float(first),
            'curvature_second_half_per_m': float(second), 'largest_toward_bevel_mm': float(bend.lateral[k] * 1e3),
            'at_mm': float(bend.along[k] * 1e3), 'end_mm': float(bend.lateral[-1] * 1e3)}


def cost_figures(pairs: int = 3, depth_m: float = 0.02, speed_m_s: float = 0.005) -> dict:
    """Microseconds per substep inside the tissue, the rigid and the flexible (20 G nitinol)
    needle in turn on the default scene, in this process."""
    from tissue_sim_ros.analysis.steering import insert_path
    from tissue_sim_ros.engine.scene.scene import Scene
    times = {'rigid': [], 'flexible': []}
    for _ in range(pairs):
        for kind, sets in (('rigid', ['needle.tip.shape=bevel']), ('flexible', needle_sets('20 G nitinol'))):
            scene = Scene.from_file(sets=sets)
            insert_path(scene, scene.start_gap_m + 0.004, speed_m_s)          # to 4 mm past the surface
            steps0, wall0 = scene.simulation.step_count, time.perf_counter()
            insert_path(scene, depth_m - 0.004, speed_m_s)
            times[kind].append((time.perf_counter() - wall0) / (scene.simulation.step_count - steps0) * 1e6)
    rigid, flexible = np.array(times['rigid']), np.array(times['flexible'])
    return {'rigid_us': rigid.tolist(), 'flexible_us': flexible.tolist(),
            'ratio_median': float(np.median(flexible / rigid)), 'pairs': pairs}


def main(*, parts=PARTS, depth_mm=80.0, speed_mm_s=5.0, jobs=None, out=None) -> dict:
    """``tissue-sim bench steering``: the parts asked for, printed (module docstring)."""
    figures = {}
    speed = speed_mm_s * 1e-3
    if 'air' in parts:
        a = figures['air'] = air_figures()
        print(f"in air, {a['segments']} segments, clamped 80 mm 20 G nitinol rod: small tip load "
              f"({a['small_load']['load_n'] * 1e3:.3g} mN): deflection {a['small_load']['deflection_m'] * 1e6:.3f} um, "
              f"{100 * a['small_load']['error']:+.3f} % from F L^3 / (3 E I)")
        for e in a['elastica']:
            print(f"  elastica F L^2 / EI = {e['load_ratio']:g}: tip rotation {e['tip_rotation_deg']:.1f} deg (rod "
                  f"{e['rod_tip_rotation_deg']:.1f}); tip x {100 * e['x_error']:+.3f} %, z {100 * e['z_error']:+.3f} %")
    if 'tissue' in parts:
        figures['tissue'] = tissue_figures(depth_mm * 1e-3, speed, jobs)
        for f in figures['tissue']:
            print(f"default tissue, {f['needle']}, {f['depth_mm']:.0f} mm at {speed_mm_s:g} mm/s: tip deflection "
                  f"{f['tip_deflection_mm']:.3f} mm ({f['toward_bevel_mm']:+.3f} mm toward the bevel; turned 180 deg: "
                  f"{f['bevel_180_toward_bevel_0_mm']:+.3f} mm), radius over the last 60 % {f['radius_m']:.3g} m "
                  f"(spread of its thirds {100 * f['spread']:.0f} %); the bevel's own bend {f['own_bend_mm']:+.3f} mm, "
                  f"radius {f['own_radius_m']:.3g} m (spread {100 * f['own_spread']:.0f} %); conical tip "
                  f"{f['conical_deflection_mm']:.3f} mm; {f['wall_s']:.0f} s a run")
    if 'phantom' in parts:
        figures['phantom'] = phantom_figures(speed, jobs)
        for f in figures['phantom']:
            print(f"phantom ({f['tissue']}), {f['needle']} (EI {f['bending_stiffness_nm2'] * 1e3:.3g} mN m^2): the "
                  f"bevel's own bend {f['own_bend_mm']:+.3f} mm, radius {f['own_radius_m']:.3g} m "
                  f"(spread {100 * f['own_spread']:.0f} %)")
    if 'flip' in parts:
        f = figures['flip'] = flip_figures(speed)
        print(f"flip: turned 180 deg at {f['flip_at_mm']:.0f} mm: curvature {f['curvature_first_half_per_m']:+.3g} 1/m "
              f"before, {f['curvature_second_half_per_m']:+.3g} 1/m after; the path went "
              f"{f['largest_toward_bevel_mm']:+.3f} "
              f"mm toward the first bevel (at {f['at_mm']:.1f} mm) and ended at {f['end_mm']:+.3f} mm")
    if 'cost' in parts:
        f = figures['cost'] = cost_figures()
        print(f"step cost inside the default scene, paired in this process: rigid "
              f"{', '.join(f'{v:.0f}' for v in f['rigid_us'])} us, flexible "
              f"{', '.join(f'{v:.0f}' for v in f['flexible_us'])} us a substep: flexible/rigid {f['ratio_median']:.3f} "
              f"(median of {f['pairs']} pairs)")
    if out is not None:
        Path(out).mkdir(parents=True, exist_ok=True)
        (Path(out) / 'steering.json').write_text(json.dumps(figures, indent=1))
    return figures
