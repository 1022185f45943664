"""The fitted keys (analysis/calibration/parameters.py): a bad --fit option is one error line naming
it, and a fitted value reaches the scene as the same number."""

import pytest


@pytest.mark.parametrize('fit, says', [
    ('regions[0].young_modulus_pa', 'expected KEY=LOW:HIGH'),
    ('regions[0].young_modulus_pa=50000:5000', 'LOW < HIGH'),
    ('regions[0].young_modulus_pa=0:5000:log', 'log scale needs LOW > 0'),
    ('regions[0].young_modulus_pa=a:5000', "'a'"),
    ('regions[0].stiffness=1:2', 'unknown scene key regions[0].stiffness'),
    ('regions[0].poisson_ratio=0.3:0.6', 'regions[0].poisson_ratio = 0.6'),
    ('model.geometric=0:1', 'is not a number'),
])
def test_a_bad_fit_option_is_one_error_line_naming_it(cheap_study, tmp_path, capsys, fit, says):
    from tissue_sim_ros.cli import main
    status = main(['calibrate', '--data-spec', str(cheap_study), '--fit', fit, '--out', str(tmp_path)])
    error = capsys.readouterr().err.strip().splitlines()[-1]
    print(error)
    assert status == 2 and error.startswith('tissue-sim calibrate: error:') and says in error


@pytest.mark.parametrize('value', [0.0, 1e-10, 2.5e-7, 1e20, 12345.678])
def test_a_fitted_value_reaches_the_scene_as_the_same_number(value):
    """A fitted value is set by its key path as a number (YAML 1.1 would read 1e-10 as text)."""
    from tissue_sim_ros.engine.scene.checks import apply_schema
    from tissue_sim_ros.engine.scene.keys import get_key, set_key
    from tissue_sim_ros.engine.scene.schema import SCHEMA
    key = 'regions[0].friction.retraction_constant_n'
    spec = apply_schema('', set_key({}, key, value), SCHEMA)
    assert get_key(spec, key) == value
