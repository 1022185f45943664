"""``solver.mass_scaling: auto``: the mass scaling, and with it the time step, chosen from the scene.

The rule:

- the time step is ``time_step_safety`` x the explicit critical step at the chosen mass scaling
  s, as for any scene (the critical step grows as sqrt(s));
- s is the largest whose measured error on the scene's own insertion is within
  ``solver.inertia_error_bound``. The insertion is the chart's task (the needle from 1 mm above
  the surface, 12 mm at ``solver.design_speed_m_s``), so the material, the mesh and the needle
  speed decide it: a softer or denser tissue, a finer mesh, a faster needle allow less. The error
  is the chart's (axial force NRMSE) against the same insertion at REFERENCE_SCALING, a run the
  rule makes first.

*Measured, not estimated:* the per-run estimate (:mod:`tissue_sim_ros.engine.solver.inertia_estimate`)
is first order (the added force while loading, and the punctures it moves earlier), 0.79-0.85
of the measured error on the default scene from 100x up, and at smaller scalings it is an
expectation over where the force samples fall (25x: 0.011-0.024 estimated, 0.0024-0.059
measured; docs/performance.md). A bound wants the error itself.

It is found by probes, from s = START:

    within the bound:  s - 1 <- (s - 1) * bound / e(s)          (assumes e grows linearly in s - 1)
    above it:          s - 1 <- (s - 1) * (bound / e(s))^2      (assumes e grows as sqrt(s - 1))

and where a step would land outside the interval between the largest probe within the bound and
the smallest above it, the geometric mean of the two (the error jumps where the scaling moves a
puncture: bisection finds that edge); until a step changes s by less than 10 %, the interval is
narrower than 10 %, or after MAX_PROBES probes, within [REFERENCE_SCALING,
MAX_SCALING]. The answer is the largest probe within the bound (the reference's scaling if none
was). A probe that fails (diverges, refused) counts as above the bound.

``auto`` is resolved once per scene (a hash of its keys, the design speed and bound included)
and cached in the user cache like ``model: auto``; the probes take a minute or two on the
default scene, said on stderr.
"""
from __future__ import annotations

import json
import math
import sys
from pathlib import Path

from tissue_sim_ros.errors import SceneError

__all__ = ['REFERENCE_SCALING', 'START', 'MAX_SCALING', 'MAX_PROBES', 'choose_mass_scaling', 'auto_mass_scaling']

#: the mass scaling of the run the probes are measured against (on the default scene at 5 mm/s
#: the chart measured 25x at 0.017 from the unscaled run: 4x is within the bounds one asks for)
REFERENCE_SCALING = 4.0
START = 16.0
MAX_SCALING = 1e4
MAX_PROBES = 6


def choose_mass_scaling(error, bound: float, *, start: float = START, lowest: float = 1.0):
    """The rule (module docstring) over ``error(s)`` -> the error at mass scaling s. Returns
    (s, probes): probes a list of {'mass_scaling', 'error'} in the order run; ``lowest`` the
    answer when no probe is within the bound."""
    probes, best, ceiling, s = [], lowest, math.inf, start
    for _ in range(MAX_PROBES):
        e = error(s)
        probes.append({'mass_scaling': s, 'error': e})
        within = e <= bound
        if within:
            best = max(best, s)
        else:
            ceiling = min(ceiling, s)
        ratio = MAX_SCALING if e <= 0 else bound / e
        following = 1.0 + (s - 1.0) * (ratio if within else ratio * ratio)
        following = min(MAX_SCALING, max(lowest, following))
        if ceiling < math.inf and (following <= best or following >= ceiling):
            following = math.sqrt(best * ceiling)   # between the largest within and the smallest above
        if following <= best or following == s or abs(following - s) < 0.1 * min(s, following) \
                or ceiling < 1.1 * best:
            break
        s = float(f'{following:.3g}')          # a value a person would write in a scene
    return best, probes


def auto_mass_scaling(spec: dict, base_dir='.', *, quiet=False) -> tuple[float, dict]:
    """The mass scaling ``solver.mass_scaling: auto`` stands for in ``spec``, and the record of
    how (bound, design speed, probes), from the per-user cache (``mass_scaling/<hash>.json``),
    else found now by probes (said on stderr) and cached."""
    from tissue_sim_ros.analysis.charting.chart import force_nrmse, make_job, simulate_job
    from tissue_sim_ros.engine.scene.scene import scene_yaml
    from tissue_sim_ros.system.user_cache import scene_cache_entry, write_whole
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

    def say(line):
        if not quiet:
            print(line, file=sys.stderr, flush=True)

    def probe(s):
        config = dict(model='scene', mesh='scene', integrator=solver['integrator'], reference=False,
                      values={'solver.mass_scaling': s})
        return simulate_job(make_job(config, scene_file, (), speed=speed))

    say(f'tissue_sim_ros: solver.mass_scaling: auto: probing for the largest mass scaling within a force '
        f'NRMSE of {bound:g} against {REFERENCE_SCALING:g}x at {speed * 1e3:g} mm/s (once; cached in {cache})')
    reference = probe(REFERENCE_SCALING)
    if reference.get('failure'):
        raise SceneError(f'solver.mass_scaling = auto: the reference run at {REFERENCE_SCALING:g}x failed '
                         f"({reference['failure']}); give solver.mass_scaling a number")
    say(f"  reference {REFERENCE_SCALING:g}x: {reference['cost_s_per_sim_s']:.2f} s per simulated s")

    def error(s):
        row = probe(s)
        if row.get('failure'):
            say(f"  mass scaling {s:g}: failed ({row['failure']})")
            return float('inf')             # a probe that fails is above any bound: step down
        e = force_nrmse(row['axial_force'], reference['axial_force'])
        estimate = row['inertia_error_estimate']
        say(f"  mass scaling {s:g}: force NRMSE {e:.4f} against {REFERENCE_SCALING:g}x"
            + ('' if estimate is None else f' (the run estimated {estimate:.4f})')
            + f", {row['cost_s_per_sim_s']:.2f} s per simulated s")
        return e

    chosen, probes = choose_mass_scaling(error, bound, lowest=REFERENCE_SCALING)
    record = dict(mass_scaling=chosen, inertia_error_bound=bound, design_speed_m_s=speed,
                  reference_mass_scaling=REFERENCE_SCALING, probes=probes)
    write_whole(cached, json.dumps(record, indent=1))
    return chosen, record
