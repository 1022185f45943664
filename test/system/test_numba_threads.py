"""numba's threading policy (system/numba_threads.py) holds even when numba was imported first."""

import os
import subprocess
import sys


def test_numba_imported_before_the_engine_still_gets_the_threading_policy():
    env = {k: v for k, v in os.environ.items() if k != 'NUMBA_THREADING_LAYER'}
    code = ('import numba\nfrom tissue_sim_ros.engine import mesh\n'
            'print(numba.config.THREADING_LAYER)')
    r = subprocess.run([sys.executable, '-c', code], env=env, capture_output=True, text=True,
                       timeout=120)
    assert r.returncode == 0 and r.stdout.strip() == 'omp', (r.stdout, r.stderr)
