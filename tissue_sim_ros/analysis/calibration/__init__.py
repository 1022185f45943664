"""``tissue-sim calibrate`` and ``tissue-sim propose``: scene keys fitted to load-cell trials,
cross-validated across speeds, and the layered scene that starts them.

- :mod:`.parameters`: the fitted keys (``--fit KEY=LOW:HIGH[:log]``) and the phase each acts on;
- :mod:`.stages`: the staged start layer by layer: which samples each fitted key acts on;
- :mod:`.objective`: the comparison's residuals of every fitted trial as one vector;
- :mod:`.repeat_draws`: each repeat's own rupture forces and layer depths, read from its punctures;
- :mod:`.evaluation_log`: ``evaluations.jsonl``, each evaluation once across resumes;
- :mod:`.search`: the staged start, the global stage, the joint bounded refinement;
- :mod:`.fine`: coarse to fine, the finish on the scene as asked;
- :mod:`.report`: what ``calibrate`` writes;
- :mod:`.calibrate`: the command;
- :mod:`.layer_estimates`: a layered curve's features and the starting values they give;
- :mod:`.layer_resolution`: how many of the mesh's elements a layer is thick along the needle;
- :mod:`.fit_bounds`: the ``--fit`` keys and bounds a proposal is calibrated with;
- :mod:`.propose_report`: what ``propose`` writes;
- :mod:`.propose`: the command ``propose``: the layers the repeats share, as a scene.
"""
__all__ = ['calibrate', 'evaluation_log', 'fine', 'fit_bounds', 'layer_estimates', 'layer_resolution', 'objective', 'parameters',
           'propose', 'propose_report', 'repeat_draws', 'report', 'search', 'stages']
