"""The environment of a child Python process that must import tissue_sim_ros from a given source
tree (this one, or another revision's): that tree first on PYTHONPATH, the caller's entries after.
Standard library only: the compile processes use it before numba is imported."""
import os

__all__ = ['importing_from']


def importing_from(root, env=None) -> dict:
    """A copy of ``env`` (default os.environ) with ``root`` first on PYTHONPATH."""
    env = dict(os.environ if env is None else env)
    env['PYTHONPATH'] = os.pathsep.join([str(root)] + [p for p in [env.get('PYTHONPATH')] if p])
    return env
