"""``python -m tissue_sim_ros.cli``: the tissue-sim command."""
import sys

from tissue_sim_ros.cli import main

sys.exit(main())
