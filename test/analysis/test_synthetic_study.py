"""A load-cell study made by the simulator (analysis/synthetic_study.py): the files it writes read
back, through their own data description, as the scene's insertion plus white noise of the size
asked for, on a jittered 10 ms grid, with each trial's speed and repeat. Truth: the same
insertion run again here (the simulation is deterministic), and the noise's own statistics."""
import numpy as np
import pytest

from tissue_sim_ros.analysis.insertion import run_insertion
from tissue_sim_ros.analysis.synthetic_study import PHANTOM_MESHES, phantom_scene, write_synthetic_study
from tissue_sim_ros.engine.scene.build import build_mesh
from tissue_sim_ros.engine.scene.checks import apply_schema
from tissue_sim_ros.engine.scene.schema import SCHEMA
from tissue_sim_ros.engine.scene.scene import Scene
from tissue_sim_ros.io.trials.data_spec import DataSpec, load_trials

SETS = ['mesh.generator=box', 'mesh.divisions=[5,5,4]', 'regions[0].membrane.criterion=none',
        'needle.start_gap_m=0.001']


def test_the_trials_are_the_insertion_plus_the_noise_asked_for(tmp_path):
    spec = write_synthetic_study(tmp_path, SETS, [6.0], travel_m=0.005, hold_s=0.2, repeats=3,
                                 noise_n=0.004, seed=3)
    truth = run_insertion(Scene.from_file(None, sets=SETS), 0.006, 0.005, hold_s=0.2, tick=0.01)
    trials = load_trials(DataSpec.from_file(spec))
    assert sorted((t.speed_m_s, t.repeat) for t in trials) == [(0.006, 1), (0.006, 2), (0.006, 3)]
    noise = []
    for trial in trials:
        grid = np.arange(trial.n_samples) * 0.01
        offset = trial.time_s - grid
        assert np.all((offset >= 0.0) & (offset < 0.001)) and np.ptp(offset) < 1e-6   # one jitter a trial
        assert trial.time_s[-1] < truth.time[-1]
        travel = np.interp(trial.time_s, truth.time, truth.travel)
        # from its first sample; to the file's 6 decimals of s and mm (0.5 us at 6 mm/s: 3 nm)
        np.testing.assert_allclose(trial.travel_m, travel - travel[0], rtol=0, atol=5e-9)
        noise.append(trial.axial_force_n - np.interp(trial.time_s, truth.time, truth.axial_force))
    noise = np.concatenate(noise)
    assert np.ptp(truth.axial_force) > 20 * 0.004                   # the curve is far above the noise
    assert noise.std() == pytest.approx(0.004, rel=0.15) and abs(noise.mean()) < 0.001


@pytest.mark.parametrize('mesh', sorted(PHANTOM_MESHES))
def test_no_phantom_mesh_puts_an_element_centroid_within_a_boundarys_spread_of_it(mesh):
    """A repeat's drawn boundary depth moves where the needle meets the layer, not which elements
    are in it: on every phantom mesh (graded across the needle's path or not) no element centroid
    lies nearer the three-layer phantom's boundary planes than their depth spread. Truth: the
    mesh's own element centroids."""
    scene = phantom_scene(3, mesh)
    built = build_mesh(apply_schema('mesh', scene['mesh'], SCHEMA['mesh']), '.')
    z = built.rest_positions[built.tetrahedra].mean(axis=1)[:, 2]
    for region in scene['regions'][1:]:
        assert np.abs(z - region['select']['below_z_m']).min() >= region['depth_spread_m'] - 1e-12


def test_a_layered_study_made_again_with_the_same_inputs_is_kept_and_with_others_made_anew(tmp_path, monkeypatch):
    """A benchmark resumed keeps its data: the second call finds what made the study in its
    truth.json and simulates nothing (the simulation runner is made to fail); another noise, or a
    trial file gone, makes it again. Truth: the files' own bytes, and the insertion run again here with the noise's statistics."""
    from tissue_sim_ros.analysis import jobs
    from tissue_sim_ros.analysis.synthetic_study import write_layered_study
    options = dict(travel_m=0.005, hold_s=0.2, repeats=2, seed=3, workers=1)
    spec = write_layered_study(tmp_path, SETS, [6.0], noise_n=0.004, **options)
    files = {p.name: p.read_bytes() for p in tmp_path.iterdir()}
    real = jobs.run_jobs

    def refuse(*args, **kwargs):
        raise AssertionError('simulated again')
    monkeypatch.setattr(jobs, 'run_jobs', refuse)
    assert write_layered_study(tmp_path, SETS, [6.0], noise_n=0.004, **options) == spec
    assert {p.name: p.read_bytes() for p in tmp_path.iterdir()} == files
    with pytest.raises(AssertionError, match='simulated again'):
        write_layered_study(tmp_path, SETS, [6.0], noise_n=0.002, **options)
    assert not (tmp_path / 'truth.json').exists()         # a study cut short is not taken for whole
    monkeypatch.setattr(jobs, 'run_jobs', real)
    write_layered_study(tmp_path, SETS, [6.0], noise_n=0.002, **options)
    truth = run_insertion(Scene.from_file(None, sets=SETS), 0.006, 0.005, hold_s=0.2, tick=0.01)
    noise = np.concatenate([t.axial_force_n - np.interp(t.time_s, truth.time, truth.axial_force)
                            for t in load_trials(DataSpec.from_file(spec))])
    assert noise.std() == pytest.approx(0.002, rel=0.2)    # made anew, with the noise now asked for
    (tmp_path / 'trial_6_2.csv').unlink()
    monkeypatch.setattr(jobs, 'run_jobs', refuse)
    with pytest.raises(AssertionError, match='simulated again'):
        write_layered_study(tmp_path, SETS, [6.0], noise_n=0.002, **options)
