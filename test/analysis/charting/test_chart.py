"""tissue-sim chart (analysis/charting/chart.py): the reference row, the linear model against the full
one, the Pareto front against a brute-force definition, and rows reproducible from their
overrides."""

import csv
import shlex

import numpy as np
import pytest

from tissue_sim_ros.analysis.charting import chart
from tissue_sim_ros.engine.scene.scene import Scene
from tissue_sim_ros.system.paths import shared_file

MEDIUM = chart.MESHES['medium']


def _config(model, reference=False, extra=None):
    return dict(task='insertion', model=model, mesh='medium', integrator='explicit', mass_scaling=None,
                reference=reference, values={**chart.MODELS[model], **MEDIUM, **(extra or {})})


@pytest.fixture(scope='module')
def small_chart(tmp_path_factory):
    """The medium mesh: the reference is the full model at mass scaling 25 (a quarter of the
    scene's step); linear and full at the scene's 400, 10 mm of travel."""
    out = tmp_path_factory.mktemp('chart')
    jobs = [chart.make_job(c, travel=0.010) for c in (
        _config('full', reference=True, extra={'solver.mass_scaling': 25.0}), _config('linear'), _config('full'))]
    report = chart.run_chart(jobs=jobs, out=out, workers=1, quiet=True, travel=0.010)
    return out, report


def test_reference_row_and_linear_against_full(small_chart):
    out, report = small_chart
    reference, linear, full = report['rows']
    assert reference['reference'] and reference['error'] == 0.0
    assert not linear['failure'] and not full['failure']
    assert linear['tetrahedra'] == full['tetrahedra'] == reference['tetrahedra']
    # the small-strain model is further from the reference than the full model on the same mesh
    assert linear['error'] > full['error'] > 0.0
    assert reference['cost_s_per_sim_s'] > full['cost_s_per_sim_s']     # a quarter of the step costs more
    for name in ('chart.csv', 'chart.png', 'chart.md', 'chart.json'):
        assert (out / name).stat().st_size > 0


def test_csv_rows_reproduce_from_their_overrides(small_chart):
    out, report = small_chart
    rows = list(csv.DictReader((out / 'chart.csv').open()))
    assert [r['reference'] for r in rows] == ['True', 'False', 'False']
    for row in rows:
        words = shlex.split(row['overrides'])
        assert words[::2] == ['--set'] * (len(words) // 2)
        scene = Scene.from_file(None, sets=words[1::2])
        assert scene.mesh.n_elements == int(row['tetrahedra'])
        assert scene.dt == pytest.approx(float(row['time_step_s']), rel=1e-5)     # the CSV's 6 digits


def test_pareto_front_against_brute_force():
    rng = np.random.default_rng(3)
    rows = [dict(reference=False, cost_s_per_sim_s=float(c), error=float(e))
            for c, e in rng.uniform(0.1, 10, size=(40, 2))]
    rows += [dict(reference=True, cost_s_per_sim_s=100.0, error=0.0), dict(reference=False, error=None)]
    chart._pareto(rows)
    points = np.array([[r['cost_s_per_sim_s'], r['error']] for r in rows[:40]])
    for k, r in enumerate(rows[:40]):
        dominated = np.any(np.all(points <= points[k], axis=1) & np.any(points < points[k], axis=1))
        assert r['pareto'] == (not dominated)
    assert not rows[40]['pareto'] and not rows[41]['pareto']
    assert sum(r['pareto'] for r in rows) >= 1


def test_grid_covers_the_axes():
    rows = chart.configurations(1e-3, quick=True)
    assert rows[0]['reference'] and sum(r['reference'] for r in rows) == 1
    assert {r['mesh'] for r in rows if r['task'] == 'insertion'} == {'coarse', 'medium', 'scene'}
    assert {r['integrator'] for r in rows} == {'explicit', 'implicit', 'quasi_static'}
    assert {chart._model_family(r['model']) for r in rows} == {'linear', 'physical', 'geometric', 'full'}
    assert {r['task'] for r in rows} == {'insertion', 'compression'}
    assert {r['integrator'] for r in rows if r['task'] == 'compression'} == {'explicit', 'implicit', 'quasi_static'}
    assert 'fine' in {r['mesh'] for r in chart.configurations(1e-3, quick=False)}
    unscaled = [r for r in chart.configurations(1e-3, quick=False) if r['integrator'] == 'implicit'
                and r['mass_scaling'] == 1.0]
    assert len(unscaled) == 1 and unscaled[0] not in rows     # the quick preset's time (chart.py)
    at_scene_step = [r for r in rows if r['task'] == 'insertion' and r['integrator'] == 'implicit'
                     and r['values']['solver.time_step_s'] == 1e-3]
    assert at_scene_step == []                                 # dominated by the explicit row (chart.py)
    selective = [r for r in rows if 'solver.selective_mass_scaling' in r['values'] and not r['reference']]
    assert sorted(r['values']['solver.selective_mass_scaling'] for r in selective) == list(chart.SELECTIVE_SCALINGS)
    assert all(r['model'] == 'full' and r['integrator'] == 'explicit' and 'solver.mass_scaling' not in r['values']
               for r in selective)
    assert any(r['integrator'] == 'quasi_static' and r['task'] == 'insertion' for r in rows)


def test_plate_compression_rows_against_the_analytic_force():
    """The linear model's uniaxial stress state is exact on linear tetrahedra: the quasi-static
    row's plate force equals E A strain within its Newton tolerance (1e-6 of the forces; 4e-8
    measured). The explicit run at the scene's mass scaling
    400 has not settled after its hold (the heavy, damped cube's slow mode): a larger error."""
    rows = {}
    for config in chart.configurations(1e-3, quick=True):
        if config['task'] == 'compression' and config['model'] == 'linear' and config['divisions'] == 4:
            rows[config['integrator']] = chart.simulate_job(chart.make_job(config))
    assert set(rows) == {'explicit', 'implicit', 'quasi_static'}
    assert rows['quasi_static']['error'] < 1e-6
    assert rows['quasi_static']['time_step_s'] == pytest.approx(10 * rows['explicit']['time_step_s'])
    assert rows['explicit']['error'] > 100 * rows['quasi_static']['error']
    assert all(not r['failure'] and r['cost_s_per_sim_s'] > 0 for r in rows.values())


def test_the_chart_scores_the_insertion_a_scene_plans():
    example = shared_file('config/organ_example.yaml')
    assert chart.insertion_task(example) == dict(travel_m=0.0419, start_gap_m=None, planned=True)
    assert chart.insertion_task(None) == dict(travel_m=chart.DEFAULT_TRAVEL_M, start_gap_m=chart.START_GAP_M,
                                              planned=False)
    assert chart.insertion_task(example, travel=0.02)['travel_m'] == 0.02


def test_the_reference_alone_takes_the_selective_mass_scaling_asked():
    """--reference-selective R: the reference row runs with solver.selective_mass_scaling R,
    the other rows as without it; the report names it with the reference's own inertia estimate."""
    rows = chart.configurations(1e-3, quick=True, reference_selective=8.0)
    assert rows[0]['reference'] and rows[0]['values']['solver.selective_mass_scaling'] == 8.0
    assert rows[1:] == chart.configurations(1e-3, quick=True)[1:]
    assert 'solver.selective_mass_scaling' not in chart.configurations(1e-3, quick=True)[0]['values']
    line = chart._reference_line([dict(rows[0], inertia_error_estimate=0.0012)])
    assert line == ('Reference: the full model, explicit, no mass scaling, selective mass scaling 8; '
                    'its estimated inertia error 0.0012.')


def test_a_row_past_its_wall_time_limit_stops_and_says_so():
    """row_limit_s: every insertion row but the reference gets the limit, outside the job's key
    (a limited run resumes an unlimited one); a row past it ends as a failure naming the limit and
    how far it got, which the chart's errors and Pareto front skip."""
    limited = chart.jobs_for(None, [], quick=True, speed=0.005, travel=None, row_limit_s=0.0)
    plain = chart.jobs_for(None, [], quick=True, speed=0.005, travel=None)
    assert [j['key'] for j in limited] == [j['key'] for j in plain]
    assert [j.get('wall_limit_s') for j in limited] == [None if j['reference'] else 0.0 for j in limited]
    row = chart.simulate_job(next(j for j in limited if j['task'] == 'insertion' and j['mesh'] == 'coarse'))
    assert row['failure'].startswith('stopped at its wall-time limit of 0 s, ')
    rows = [dict(row, task='insertion'), dict(reference=True, task='insertion', failure='', axial_force=[0.0, 1.0],
                                             puncture_depth_m=None, cost_s_per_sim_s=10.0)]
    chart._errors(rows)
    chart._pareto(rows)
    assert rows[0]['error'] is None and not rows[0]['pareto']
