"""The bovine-liver measurement as a study (analysis/compare/reference_data.py): the committed files
are what the digitized trace makes, and the layered scene packaged for it holds the whole trace."""

import pytest

matplotlib = pytest.importorskip('matplotlib')


def test_the_committed_bovine_liver_study_is_what_the_digitized_file_makes(tmp_path):
    """data/okamura2004_bovine_liver/{study.yaml, liver_3mm_s_trace1.csv} are written by
    reference_data from the digitized file: made afresh, they are byte for byte the same."""
    from tissue_sim_ros.analysis.compare.reference_data import DATA_DIR, write_bovine_liver_study
    made = write_bovine_liver_study(tmp_path)
    for name in ('study.yaml', 'liver_3mm_s_trace1.csv'):
        assert (tmp_path / name).read_bytes() == (DATA_DIR / name).read_bytes(), name
    assert made == tmp_path / 'study.yaml'


def test_the_layered_bovine_liver_scene_holds_the_whole_trace_with_its_inner_structures():
    """config/bovine_liver_layered.yaml (the capsule and the three inner structures as layers,
    proposed from the trace and calibrated on it) against the measured trace to 48 mm: NRMSE at
    most 0.10 over every sample, the puncture windows kept (the one-layer default scene: 0.146),
    at most 0.06 without them, and each of the trace's four punctures made within 1 mm of its
    depth by the layer it belongs to."""
    from support.paths import ROOT
    from tissue_sim_ros.analysis.compare.compare import compare_trials
    from tissue_sim_ros.analysis.compare.reference_data import study_path
    from tissue_sim_ros.engine.scene.scene import Scene
    from tissue_sim_ros.io.trials.data_spec import DataSpec, load_trials
    trials = load_trials(DataSpec.from_file(study_path()))
    scene = Scene.from_file(ROOT / 'config' / 'bovine_liver_layered.yaml')
    comparison = compare_trials(trials, scene, align='depth', quiet=True)['comparisons'][0]
    measured, simulated = comparison.measured_punctures, comparison.simulated_punctures
    depths = [[round(p.travel_m * 1e3, 2) for p in punctures] for punctures in (measured, simulated)]
    print(f"NRMSE {comparison.errors['nrmse_all_samples']:.4f} over every sample, "
          f"{comparison.errors['nrmse']:.4f} without the puncture windows; punctures measured at "
          f'{depths[0]} mm, made at {depths[1]}')
    assert comparison.errors['nrmse_all_samples'] <= 0.10 and comparison.errors['nrmse'] <= 0.06
    assert [p.layer for p in measured] == [p.layer for p in simulated] == [0, 1, 2, 3]
    assert all(abs(m.travel_m - s.travel_m) < 1e-3 for m, s in zip(measured, simulated))
