"""Compiled code: how the kernels are compiled, and the substeps run in one compiled call.

- :mod:`.cache`: the first start's compiles, reported and run on two cores into numba's cache;
- :mod:`.clock`: the thread CPU and monotonic clocks read from compiled code;
- :mod:`.call`: compiled functions called by address from compiled code, their types checked;
- :mod:`.substeps`: an advance's substeps in compiled slices, bit for bit the general path.
"""
__all__ = ['cache', 'call', 'clock', 'substeps']
