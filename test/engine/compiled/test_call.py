"""A compiled function called by its address from compiled code (engine.compiled_call) returns
what a direct call returns and writes the same arrays; the check of its types tells apart every
change of type a scene's arguments could see, and a caller with a stale check refuses the call."""

import numpy as np
import pytest
from numba import njit, types

from tissue_sim_ros.engine.compiled.call import call_compiled, compiled_address, signature_check

_STEP = types.Tuple((types.float64, types.float64, types.int64))


@njit(cache=False)
def _step(scale, flag, values, counts, k):
    """Writes values and counts; returns floats and an int made of all the arguments."""
    total = 0.0
    for i in range(values.shape[0]):
        values[i] = values[i] * scale + i
        total += values[i]
    counts[k] += 1
    return total, scale * 2.0 if flag else -scale, counts[k] + k


@njit(cache=False)
def _fill(values, matrix, value):
    values[:] = value
    matrix[1, :] = value * 2.0


@njit(cache=False)
def _by_address(addresses, checks, scale, flag, values, counts, k, matrix):
    """(the step's three results, whether the checks held); the fill called with a leading tuple."""
    if (checks[0] != signature_check((scale, flag), (values, counts, k), (0.0, 0.0, 0))
            or checks[1] != signature_check((values,), (matrix, 3.5), None)):
        return 0.0, 0.0, -1, False
    total, other, count = call_compiled(addresses[0], (scale, flag), (values, counts, k), (0.0, 0.0, 0))
    call_compiled(addresses[1], (values,), (matrix, 3.5), None)
    return total, other, count, True


def _arrays():
    return np.linspace(0.0, 1.0, 7), np.zeros(4, dtype=np.int64), np.zeros((3, 5))


def _functions(values, counts, matrix):
    step = compiled_address(_step, (1.5, True, values, counts, 2), _STEP)
    fill = compiled_address(_fill, (values, matrix, 3.5), types.none)
    return np.array([step[0], fill[0]]), np.array([step[1], fill[1]])


def test_a_call_by_address_is_the_direct_call():
    values, counts, matrix = _arrays()
    addresses, checks = _functions(values, counts, matrix)
    total, other, count, held = _by_address(addresses, checks, 1.5, True, values, counts, 2, matrix)
    direct_values, direct_counts, direct_matrix = _arrays()
    expected = _step(1.5, True, direct_values, direct_counts, 2)
    assert held and (total, other, count) == expected
    assert np.array_equal(counts, direct_counts) and counts[2] == 1
    _fill(direct_values, direct_matrix, 3.5)
    assert np.array_equal(values, direct_values) and np.array_equal(matrix, direct_matrix)
    assert np.all(values == 3.5) and np.all(matrix[1] == 7.0) and np.all(matrix[0] == 0.0)


def test_a_stale_check_refuses_the_call():
    values, counts, matrix = _arrays()
    addresses, checks = _functions(values, counts, matrix)
    for k in range(2):
        stale = checks.copy()
        stale[k] += 1
        assert _by_address(addresses, stale, 1.5, True, values, counts, 2, matrix)[3] is False
    assert np.array_equal(counts, np.zeros(4, dtype=np.int64)) and np.array_equal(values, _arrays()[0])


def test_the_check_tells_apart_every_change_of_type():
    """dtype, layout (a strided view, a transposed array), rank, an int for a float, the return
    type."""
    values, counts, _ = _arrays()
    base = compiled_address(_step, (1.5, True, values, counts, 2), _STEP)[1]
    variants = [(1.5, True, values.astype(np.float32), counts, 2), (1.5, True, values[::2], counts, 2),
                (1.5, True, values, counts.astype(np.int32), 2), (1, True, values, counts, 2)]
    checks = {compiled_address(_step, args, _STEP)[1] for args in variants}
    assert len(checks) == len(variants) and base not in checks
    assert compiled_address(_step, (1.5, True, values, counts, 2), _STEP)[1] == base      # the same types
    fills = {compiled_address(_fill, (values, matrix, 3.5), types.none)[1]
             for matrix in (np.zeros((3, 5)), np.zeros((3, 5, 2)), np.zeros((5, 3)).T)}
    assert len(fills) == 3 and not fills & checks
    with pytest.raises(TypeError, match='returns'):
        compiled_address(_step, (1.5, True, values, counts, 2), types.int64)
