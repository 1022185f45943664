"""The package's errors (errors.py): one family, and an error that crosses a process (a prediction
worker's refusal, a pool worker's divergence) arrives whole. Truth: pickle's round trip, the
arguments each error was built from, and the family the module docstring draws."""
import pickle

import pytest

from tissue_sim_ros import errors
from tissue_sim_ros.errors import (DataError, InputError, PoseError, SceneError, SimulationDiverged,
                                   TissueSimError)


@pytest.mark.parametrize('error', [
    PoseError('pose.position', [0.0, float('inf'), 0.2], 'finite numbers'),
    DataError('trial.csv', 'time goes backwards', column='time', row=17),
    DataError('trial.csv', 'empty file'),
    SimulationDiverged('energy grew without input', 2500, 5.83, 0.0029, 0.0023),
    SceneError('regions[0].poisson_ratio = 0.5: expected a number in (-1, 0.5)'),
])
def test_an_error_pickled_to_another_process_arrives_whole(error):
    again = pickle.loads(pickle.dumps(error))
    assert type(again) is type(error) and str(again) == str(error)
    assert vars(again) == vars(error)


def test_each_error_names_what_it_was_given():
    pose = PoseError('pose.orientation', [1.2, 0.0, 0.0, 0.0], 'a unit quaternion')
    assert str(pose) == "pose.orientation = [1.2, 0.0, 0.0, 0.0]: a unit quaternion"
    assert (pose.field, pose.value, pose.expected) == ('pose.orientation', [1.2, 0.0, 0.0, 0.0],
                                                       'a unit quaternion')
    assert str(DataError('a.csv', 'not a number', column='fz', row=3)) == "a.csv, column 'fz', row 3: not a number"
    assert str(DataError('a.csv', 'empty file')) == 'a.csv: empty file'
    diverged = SimulationDiverged('2 inverted elements', 40, 0.25, 0.003, 0.002)
    assert 'step 40' in str(diverged) and 't = 0.25 s' in str(diverged)
    assert '(1.50x)' in str(diverged)                     # the time step over the critical one


def test_every_error_is_one_of_the_family_and_bad_input_is_a_value_error():
    """Every error the module exports is a TissueSimError; input errors are ValueErrors (callers
    that catch those still do), run-time failures RuntimeErrors."""
    exported = [getattr(errors, name) for name in errors.__all__]
    assert all(issubclass(cls, TissueSimError) for cls in exported)
    inputs = [cls for cls in exported if issubclass(cls, InputError)]
    assert all(issubclass(cls, ValueError) for cls in inputs) and len(inputs) >= 14
    for cls in exported:
        assert issubclass(cls, InputError) != issubclass(cls, RuntimeError) or cls is TissueSimError
