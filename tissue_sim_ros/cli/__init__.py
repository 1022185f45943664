"""``tissue-sim``, the command line: thin, each command a call into the layers below.

- :mod:`.arguments`: the option types and option groups every command shares;
- :mod:`.app`: the parser, the dispatch and the one-line error report (exit status 2);
- :mod:`.bench_commands`: ``tissue-sim bench`` and its benchmarks;
- :mod:`.mesh_commands`: ``tissue-sim mesh`` and ``tissue-sim organ-example``;
- :mod:`.node_commands`: the commands that run or drive the node as a process;
- :mod:`.node_script`: ``tissue_sim_node``, the node's console script.
"""
from tissue_sim_ros.cli.app import main

__all__ = ['main']
