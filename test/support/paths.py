"""Where the tests find the repository's files."""
from pathlib import Path

#: the repository root (this file is test/support/paths.py)
ROOT = Path(__file__).resolve().parents[2]
