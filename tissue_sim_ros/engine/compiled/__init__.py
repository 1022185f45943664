"""Compiled code: how the kernels are compiled, and the substeps run in one compiled call.

- :mod:`.cache`: the first start's compiles, reported and run on two cores into numba's cache;
- :mod:`.clock`: the thread CPU and monotonic clocks read from compiled code;
- :mod:`.call`: compiled functions called by address from compiled code, their types checked;
- :mod:`.outcomes`: a compiled substep's outcomes, the needle's move and the watchdog's test;
- :mod:`.substeps`: an advance's substeps in compiled slices, bit for bit the general path;
- :mod:`.rod_substeps`: the substep with a flexible needle inside.
"""
__all__ = ['cache', 'call', 'clock', 'outcomes', 'rod_substeps', 'substeps']
