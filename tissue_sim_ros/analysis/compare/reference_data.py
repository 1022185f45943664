"""The bovine-liver measurement the default scene models, as a load-cell study the commands read.

``data/okamura2004_bovine_liver/depth_force_digitized.csv`` holds several traces read off the
published figures of Okamura et al. (2004), concatenated and unsorted, with depth but no time.
The longest (the first segment: 0 to 48 mm, contact near 9 mm, capsule rupture near 19 mm) is
the insertion the default scene models. :func:`bovine_liver_trace` takes it out and sorts it by
depth; :func:`write_bovine_liver_study` writes it as ``liver_3mm_s_trace1.csv`` (time from the
depth at the reported 3 mm/s: ``time_s = depth_m / 0.003``) with ``study.yaml``, a data
description any command that takes data reads (``tissue-sim compare --data-spec
data/okamura2004_bovine_liver/study.yaml``). The two files are committed; a test checks they
are what this module makes of the digitized file.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from tissue_sim_ros.system.paths import shared_file

__all__ = ['DATA_DIR', 'SPEED_M_S', 'bovine_liver_trace', 'write_bovine_liver_study', 'study_path']

DATA_DIR = shared_file('data/okamura2004_bovine_liver')
SPEED_M_S = 0.003
TRACE_FILE = 'liver_3mm_s_trace1.csv'
STUDY_FILE = 'study.yaml'
STUDY_TEXT = f"""# The bovine-liver insertion of Okamura et al. (2004) as a study tissue-sim reads (see
# tissue_sim_ros/analysis/compare/reference_data.py): one trial at 3 mm/s, digitized, time from depth.
files: ['{TRACE_FILE}']
time: {{column: time_s, unit: s}}
force: {{column: force_n, unit: N, sign: 1}}
position: {{column: depth_m, unit: m, sign: 1}}
motion: {{speed_mm_s: 3.0}}
"""


def data_dir() -> Path:
    """The data folder: the source tree's, else the installed share/ one."""
    if DATA_DIR.exists():
        return DATA_DIR
    try:
        from ament_index_python.packages import get_package_share_directory
        return Path(get_package_share_directory('tissue_sim_ros')) / 'data' / 'okamura2004_bovine_liver'
    except Exception:                   # no ament index: the source-tree path, as it is
        return DATA_DIR


def study_path() -> Path:
    return data_dir() / STUDY_FILE


def bovine_liver_trace() -> tuple[np.ndarray, np.ndarray]:
    """The longest digitized trace (segment 1), sorted by depth, repeated depths dropped:
    (depth [m], axial force [N])."""
    data = np.loadtxt(data_dir() / 'depth_force_digitized.csv', delimiter=',')
    restarts = np.flatnonzero(np.diff(data[:, 0]) < -0.01) + 1     # the depth jumps back to ~0
    first = data[:restarts[0]] if len(restarts) else data
    first = first[np.argsort(first[:, 0], kind='stable')]
    keep = np.concatenate([[True], np.diff(first[:, 0]) > 0])
    return first[keep, 0], first[keep, 1]


def write_bovine_liver_study(directory=None) -> Path:
    """Write the trace and its data description into ``directory`` (default: the data folder);
    the description's path."""
    directory = Path(directory) if directory is not None else data_dir()
    depth, force = bovine_liver_trace()
    with open(directory / TRACE_FILE, 'w') as handle:
        handle.write('time_s,depth_m,force_n\n')
        for d, f in zip(depth, force):
            handle.write(f'{d / SPEED_M_S:.9g},{d:.9g},{f:.9g}\n')
    (directory / STUDY_FILE).write_text(STUDY_TEXT)
    return directory / STUDY_FILE
