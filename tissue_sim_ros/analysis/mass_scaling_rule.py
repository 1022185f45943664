"""``solver.mass_scaling: auto``: the mass scaling, and with it the time step, chosen from the scene.

The rule:

- the time step is ``time_step_safety`` x the explicit critical step at the chosen mass scaling
  s, as for any scene (the critical step grows as sqrt(s));
- s is the largest whose estimated inertia error (:mod:`tissue_sim_ros.engine.inertia_estimate`,
  the force NRMSE the scaling adds) on the scene's own insertion is within
  ``solver.inertia_error_bound``. The insertion is the chart's task (the needle from 1 mm above
  the surface, 12 mm at ``solver.design_speed_m_s``), so the material, the mesh and the needle
  speed decide it: a softer or denser tissue, a finer mesh, a faster needle allow less.

It is found by probes, from s = START:

    within the bound:  s - 1 <- (s - 1) * bound / e(s)          (assumes e grows linearly in s - 1)
    above it:          s - 1 <- (s - 1) * (bound / e(s))^2      (assumes e grows as sqrt(s - 1))

until a step within the bound changes s by less than 10 %, or after MAX_PROBES probes, within
[1, MAX_SCALING]; the answer is the largest probe within the bound (1 if none was). Up-steps
assume linear growth, down-steps square-root growth, so that a step up from a probe within the
bound mostly stays within it and a step down lands within it: the estimate grows about linearly
in s - 1 (the damping force the scaling adds is linear in it; 2.8-3.3x per 4x on the default
scene at 3 and 10 mm/s, 5x per 4.5x on a small sample), and where a step up overshoots, the next
probe steps down. A probe that fails (diverges, refused) counts as above the bound.

``auto`` is resolved once per scene (a hash of its keys, the design speed and bound included)
and cached in the user cache like ``model: auto``; the probes take seconds to a minute on the
default scene, said on stderr.
"""
from __future__ import annotations

import json
import sys
from pathlib import Path

__all__ = ['START', 'MAX_SCALING', 'MAX_PROBES', 'choose_mass_scaling', 'auto_mass_scaling']

START = 16.0
MAX_SCALING = 1e4
MAX_PROBES = 6


def choose_mass_scaling(estimate, bound: float, *, start: float = START):
    """The rule (module docstring) over ``estimate(s)`` -> the estimated error at mass scaling s
    (None: not estimated, taken as within). Returns (s, probes): probes a list of
    {'mass_scaling', 'estimate'} in the order run."""
    probes, best, s = [], 1.0, start
    for _ in range(MAX_PROBES):
        e = estimate(s)
        probes.append({'mass_scaling': s, 'estimate': e})
        within = e is None or e <= bound
        if within:
            best = max(best, s)
        ratio = MAX_SCALING if e is None or e <= 0 else bound / e
        following = 1.0 + (s - 1.0) * (ratio if within else ratio * ratio)
        following = min(MAX_SCALING, max(1.0, following))
        if following <= best or following == s or (within and abs(following - s) < 0.1 * s):
            break
        s = float(f'{following:.3g}')          # a value a person would write in a scene
    return best, probes


def auto_mass_scaling(spec: dict, base_dir='.', *, quiet=False) -> tuple[float, dict]:
    """The mass scaling ``solver.mass_scaling: auto`` stands for in ``spec``, and the record of
    how (bound, design speed, probes), from the per-user cache (``mass_scaling/<hash>.json``),
    else found now by probes (said on stderr) and cached."""
    from tissue_sim_ros.analysis.chart import make_job, simulate_job
    from tissue_sim_ros.engine.scene import scene_yaml
    from tissue_sim_ros.user_cache import scene_cache_entry
    solver = spec['solver']
    bound, speed = float(solver['inertia_error_bound']), float(solver['design_speed_m_s'])
    text = scene_yaml(spec, base_dir)
    where, key = scene_cache_entry('mass_scaling', text)
    cache = Path(where)
    cached = cache / f'{key}.json'
    if cached.exists():
        record = json.loads(cached.read_text())
        return float(record['mass_scaling']), record
    cache.mkdir(parents=True, exist_ok=True)
    scene_file = cache / f'{key}-scene.yaml'
    scene_file.write_text(text)
    if not quiet:
        print(f'tissue_sim_ros: solver.mass_scaling: auto: probing for the largest mass scaling within an '
              f'estimated inertia error of {bound:g} at {speed * 1e3:g} mm/s (once; cached in {cache})',
              file=sys.stderr, flush=True)

    def estimate(s):
        config = dict(model='scene', mesh='scene', integrator=solver['integrator'], reference=False,
                      overrides=[f'solver.mass_scaling={s!r}'])
        row = simulate_job(make_job(config, scene_file, (), speed=speed))
        if not quiet:
            print(f'  mass scaling {s:g}: ' + (f"failed ({row['failure']})" if row.get('failure') else
                  f"estimated inertia error {row['inertia_error_estimate']:.4f}, "
                  f"{row['cost_s_per_sim_s']:.2f} s per simulated s"), file=sys.stderr, flush=True)
        if row.get('failure'):
            return float('inf')             # a probe that fails is above any bound: step down
        return row['inertia_error_estimate']

    chosen, probes = choose_mass_scaling(estimate, bound)
    record = dict(mass_scaling=chosen, inertia_error_bound=bound, design_speed_m_s=speed, probes=probes)
    partial = cached.with_suffix('.partial')
    partial.write_text(json.dumps(record, indent=1))
    partial.replace(cached)                  # never a half-written cache entry
    return chosen, record
