"""Console script ``tissue_sim_node``: the ROS 2 node (needle pose in, wrench and mesh out).

The node itself is the subject of the ROS node issue and is not written yet; until then this
entry point says so plainly and exits with status 2, so ``ros2 run`` never fails obscurely.
"""
import sys


def main(argv=None):
    print('tissue_sim_node: the ROS 2 node is not implemented yet in this version of tissue_sim_ros; '
          'use `tissue-sim` for the headless engine.', file=sys.stderr)
    return 2


if __name__ == '__main__':
    sys.exit(main())
