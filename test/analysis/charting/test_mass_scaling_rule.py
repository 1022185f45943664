"""The rule of ``solver.mass_scaling: auto`` (analysis/charting/mass_scaling_rule.py): on error
curves whose crossing of the bound is known it finds the largest scaling within the bound, steps
down from a failing start and bisects to a jump; on a scene its choice is the measured one."""

import math

import pytest

from support.scenes import small_spec
from tissue_sim_ros.analysis.charting.mass_scaling_rule import MAX_PROBES, MAX_SCALING, choose_mass_scaling


def auto_scene(**options):
    """The small sample with its auto keys resolved, as every command loads a scene."""
    from tissue_sim_ros.analysis.charting.auto_keys import resolve_auto_keys
    from tissue_sim_ros.engine.scene.checks import apply_schema
    from tissue_sim_ros.engine.scene.schema import SCHEMA
    from tissue_sim_ros.engine.scene.scene import Scene
    spec, choices = resolve_auto_keys(apply_schema('', small_spec(**options), SCHEMA))
    return Scene(spec, auto_choices=choices)


@pytest.mark.parametrize('exponent', [0.5, 0.75, 1.0, 1.2])
def test_the_rule_finds_the_largest_scaling_within_the_bound(exponent):
    """On e(s) = k (s - 1)^p the probes end within the bound and near it: the crossing s* is
    known, and the answer is within 15 % of it below."""
    k, bound = 0.001, 0.02
    crossing = 1 + (bound / k) ** (1 / exponent)
    chosen, probes = choose_mass_scaling(lambda s: k * (s - 1) ** exponent, bound)
    assert len(probes) <= MAX_PROBES
    assert k * (chosen - 1) ** exponent <= bound
    assert 0.85 * crossing <= chosen <= crossing


def test_the_rule_steps_down_from_a_failing_or_too_large_start():
    chosen, probes = choose_mass_scaling(lambda s: math.inf if s > 4 else 0.001 * (s - 1), 0.02, lowest=4.0)
    assert probes[0]['error'] == math.inf and chosen == 4.0
    chosen, probes = choose_mass_scaling(lambda s: 0.01 * (s - 1), 0.02)     # crossing at 3
    assert probes[0]['mass_scaling'] == 16.0 and 2.5 <= chosen <= 3.0
    chosen, probes = choose_mass_scaling(lambda s: 0.0, 0.02)                # no error at all: the cap
    assert chosen == MAX_SCALING and len(probes) == 2


def test_auto_scene_takes_the_rule_and_caches_it(tmp_path, monkeypatch):
    """`solver.mass_scaling: auto` on the small sample: the mass scaling of the largest probe within
    the bound, whose error measured afresh against the reference scaling is the recorded one; its
    time step the critical step's fraction at it; a second load takes the cache (no probe runs)."""
    from tissue_sim_ros.analysis.charting.chart import force_nrmse, make_job, simulate_job
    from tissue_sim_ros.analysis.charting.mass_scaling_rule import REFERENCE_SCALING
    monkeypatch.setenv('XDG_CACHE_HOME', str(tmp_path))
    solver = {'mass_scaling': 'auto', 'design_speed_m_s': 0.01}
    region = {'membrane': {'criterion': 'force', 'rupture_force_n': 0.2}}
    scene = auto_scene(solver=solver, region=region)
    record = scene.auto_choices['solver.mass_scaling']
    within = [p for p in record['probes'] if p['error'] <= record['inertia_error_bound']]
    chosen = scene.simulation.mass_scaling
    assert chosen == max(p['mass_scaling'] for p in within) > REFERENCE_SCALING
    assert any(p['error'] > record['inertia_error_bound'] for p in record['probes'])   # it found the edge
    assert scene.dt == pytest.approx(0.8 * scene.simulation.critical_time_step(), rel=1e-9)

    scene_file = next(tmp_path.rglob('*-scene.yaml'))
    rows = [simulate_job(make_job(dict(model='scene', mesh='scene', integrator='explicit', reference=False,
                                       values={'solver.mass_scaling': s}), scene_file, (), speed=0.01))
            for s in (REFERENCE_SCALING, chosen)]
    measured = force_nrmse(rows[1]['axial_force'], rows[0]['axial_force'])
    assert measured == pytest.approx(next(p['error'] for p in within if p['mass_scaling'] == chosen), rel=1e-9)
    assert measured <= record['inertia_error_bound']

    import tissue_sim_ros.analysis.charting.chart as chart
    monkeypatch.setattr(chart, 'simulate_job', lambda job: pytest.fail('probed again'))
    again = auto_scene(solver=solver, region=region)
    assert again.simulation.mass_scaling == chosen


def test_the_rule_bisects_to_an_error_that_jumps():
    """A puncture moved by the scaling makes the error jump: 0.01 below s = 60, 0.06 above. The
    probes end within 10 % below the jump."""
    chosen, probes = choose_mass_scaling(lambda s: 0.01 if s < 60 else 0.06, 0.02, lowest=4.0)
    assert chosen < 60 and chosen >= 0.9 * 60 / 1.1, probes
