"""Materials (engine/model/material.py): Lame coefficients from E and nu, and refusals by field."""

import pytest

import tissue_sim_ros as ts


def test_material_lame_coefficients_and_refusals():
    m = ts.Material(young_modulus=1000.0, poisson_ratio=0.25, density=1000.0)
    assert m.lame_mu == pytest.approx(400.0, rel=1e-15)
    assert m.lame_lambda == pytest.approx(400.0, rel=1e-15)      # E nu / ((1+nu)(1-2nu))
    for field, kwargs in [('young_modulus', dict(young_modulus=0.0)),
                          ('young_modulus', dict(young_modulus=float('nan'))),
                          ('poisson_ratio', dict(poisson_ratio=0.5)),
                          ('poisson_ratio', dict(poisson_ratio=-1.0)),
                          ('density', dict(density=-1.0))]:
        args = dict(young_modulus=1e3, poisson_ratio=0.3, density=1e3) | kwargs
        with pytest.raises(ts.MaterialError, match=field):
            ts.Material(**args)
