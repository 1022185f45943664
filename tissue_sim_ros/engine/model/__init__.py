"""The tissue's material and the tensor-mass internal forces (docs/method.md).

- :mod:`.material`: Lame coefficients, the mean-ratio laws of the physical non-linearity,
  Kelvin-Voigt viscosity;
- :mod:`.kernels`: the numba element pass, one kernel per model (linear, physical, geometric,
  viscous, in any combination);
- :mod:`.simd_lanes`, :mod:`.inversion_safeguard`: the pass's vector gather and scatter, and the
  St Venant-Kirchhoff stress continued past inversion;
- :mod:`.relaxation`: the Prony-series stress relaxation;
- :mod:`.elements`: per-element rest geometry (shape-function gradients, volumes) and materials;
- :mod:`.tensor_mass`: :class:`TensorMassModel`, the per-element precomputation and the forces;
- :mod:`.edge_form`, :mod:`.reference`: the paper's vertex/edge tensor form and its precomputed
  non-linear form, second formulations the tests hold the kernels against;
- :mod:`.critical_step`: the explicit solver's critical time step of a model.
"""
__all__ = ['critical_step', 'edge_form', 'elements', 'inversion_safeguard', 'kernels', 'material', 'reference',
           'relaxation', 'simd_lanes', 'tensor_mass']
