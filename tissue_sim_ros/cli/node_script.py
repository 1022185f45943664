"""``tissue_sim_node``, the node's console script (``ros2 run tissue_sim_ros tissue_sim_node``).

The node (:mod:`tissue_sim_ros.ros.node`) imports nothing above the ROS layer; this script is
where the analysis layer's resolution of ``model: auto`` and ``solver.mass_scaling: auto`` is
handed to it, loaded only when a scene has such a key.
"""
import sys

__all__ = ['main']


def _resolve_auto(spec, base_dir):
    from tissue_sim_ros.analysis.charting.auto_keys import resolve_auto_keys
    return resolve_auto_keys(spec, base_dir)


def main(argv=None) -> int:
    from tissue_sim_ros.ros.node import main as node_main
    return node_main(argv, resolve_auto=_resolve_auto)


if __name__ == '__main__':
    sys.exit(main())
