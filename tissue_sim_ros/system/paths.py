"""Where the package's own files are: its source directory, and the shared files (``config/``,
``data/``) in a source tree or in an installed ``share/tissue_sim_ros``."""
from pathlib import Path

__all__ = ['PACKAGE_DIR', 'SOURCE_ROOT', 'shared_file']

#: the tissue_sim_ros/ directory itself
PACKAGE_DIR = Path(__file__).resolve().parents[1]
#: the directory holding tissue_sim_ros/: a source checkout's root (or site-packages)
SOURCE_ROOT = PACKAGE_DIR.parent


def shared_file(relative: str) -> Path:
    """``config/...`` or ``data/...``: the source tree's copy when there is one, else the ament
    share directory's (``colcon build``); the source-tree path when neither is found, so that an
    error names where it looked."""
    here = SOURCE_ROOT / relative
    if here.exists():
        return here
    try:
        from ament_index_python.packages import get_package_share_directory
        return Path(get_package_share_directory('tissue_sim_ros')) / relative
    except Exception:                    # no ament index (a pip install): the source-tree path
        return here
