"""Time integration of the tissue: lumped masses, damping, boundary conditions, the watchdog.

- :mod:`.explicit`: :class:`Simulation`, symplectic Euler with the stability watchdog (and the
  door to the implicit steps);
- :mod:`.implicit`: backward Euler and quasi-static steps (Newton, matrix-free CG);
- :mod:`.implicit_bonds`: the needle's bonded contact held exactly inside those steps;
- :mod:`.inertia_estimate`: the force error the mass scaling adds, estimated during a run.
"""
__all__ = ['explicit', 'implicit', 'implicit_bonds', 'inertia_estimate']
