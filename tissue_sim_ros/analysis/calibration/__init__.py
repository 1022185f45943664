"""``tissue-sim calibrate``: scene keys fitted to load-cell trials, cross-validated across speeds.

- :mod:`.parameters`: the fitted keys (``--fit KEY=LOW:HIGH[:log]``) and the phase each acts on;
- :mod:`.objective`: the comparison's residuals of every fitted trial as one vector;
- :mod:`.search`: the staged start, the global stage, the joint bounded refinement;
- :mod:`.fine`: coarse to fine, the finish on the scene as asked;
- :mod:`.report`: what ``calibrate`` writes;
- :mod:`.calibrate`: the command.
"""
__all__ = ['calibrate', 'fine', 'objective', 'parameters', 'report', 'search']
