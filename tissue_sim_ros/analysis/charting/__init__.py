"""Studies of the models and methods on a scene: what accuracy costs, where stability ends.

- :mod:`.compression`: a plate compression with an analytic answer (E A strain);
- :mod:`.chart`: speed against accuracy over models, meshes, steps and integrators;
- :mod:`.stability`: the largest stable step per model and integrator, induced failures;
- :mod:`.recommend`: the cheapest configuration within a tolerance that keeps real time;
- :mod:`.mass_scaling_rule`: the largest mass scaling within an inertia error bound;
- :mod:`.auto_keys`: ``model: auto`` and ``solver.mass_scaling: auto`` resolved into concrete
  scene keys before a scene is built.
"""
__all__ = ['auto_keys', 'chart', 'compression', 'mass_scaling_rule', 'recommend', 'stability']
