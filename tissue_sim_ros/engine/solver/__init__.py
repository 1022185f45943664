"""Time integration of the tissue: lumped masses, damping, boundary conditions, the watchdog.

- :mod:`.explicit`: :class:`Simulation`, symplectic Euler with the stability watchdog (and the
  door to the implicit steps);
- :mod:`.implicit`: backward Euler and quasi-static steps (Newton, matrix-free CG);
- :mod:`.implicit_bonds`: the needle's bonded contact held exactly inside those steps;
- :mod:`.inertia_estimate`: the force error the mass scaling adds, estimated during a run;
- :mod:`.supports`: elastic foundations and the check that the supports stop rigid motion;
- :mod:`.settle`: the tissue settled under gravity on its supports before a needle moves.
"""
__all__ = ['explicit', 'implicit', 'implicit_bonds', 'inertia_estimate', 'settle', 'supports']
