"""The bovine-liver measurement as a study (analysis/compare/reference_data.py): the committed files
are what the digitized trace makes."""

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
