"""One simulated trial as a job a worker process runs (analysis/compare/trial_simulation.py): a
process pool gives what a serial run gives."""

import numpy as np

from tissue_sim_ros.engine.scene.scene import Scene

# the tests' own tissue (the default scene's cutting and friction are calibrated, and move)
SETS = ['mesh.generator=box', 'mesh.divisions=[8,8,6]', 'regions[0].cutting_force_n=0.94',
        'regions[0].friction.insertion_coulomb_n_per_m=10.57']


def test_a_process_pool_gives_what_a_serial_run_gives():
    """Two simulations of two motions in two spawned worker processes (one numba thread each)
    against the same two in this process: the same forces, to rounding (1e-12: the contact's
    pseudo-inverse goes through LAPACK, whose sums another process may order otherwise)."""
    from tissue_sim_ros.analysis.jobs import run_jobs
    from tissue_sim_ros.analysis.compare.trial_simulation import SimulationJob, simulate
    scene = Scene.from_file(None, sets=SETS)
    start, axis = scene.needle_pose[0], scene.needle.axis.copy()
    jobs = []
    for speed in (0.004, 0.008):
        times = np.arange(1, 301) * 0.01        # 12 mm: both reach the tissue 9 mm below
        jobs.append(SimulationJob(scene.spec, str(scene.base_dir), times,
                                  start + np.minimum(times * speed, 0.012)[:, None] * axis))
    serial = run_jobs(simulate, jobs, workers=1, quiet=True)
    pooled = run_jobs(simulate, jobs, workers=2, quiet=True)
    for a, b in zip(serial, pooled):
        np.testing.assert_allclose(a.axial_force_n, b.axial_force_n, rtol=1e-12, atol=1e-12)
    assert serial[0].axial_force_n.max() > 0.05 and not np.array_equal(serial[0].axial_force_n,
                                                                      serial[1].axial_force_n)
