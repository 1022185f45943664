"""Independent simulations over the cores (analysis/jobs.py): a failed job ends the batch without
waiting for the others, in its own pool and in a pool kept open across batches."""

import time

import pytest

from tissue_sim_ros.analysis.jobs import run_jobs


@pytest.mark.parametrize('own_pool', [False, True])
def test_a_failed_job_ends_the_batch_without_waiting_for_the_others(own_pool):
    """One job fails at once (time.sleep of a string) while another sleeps 60 s: run_jobs raises
    the failure within seconds, in its own pool and in a WorkerPool kept open across batches,
    instead of waiting for the sleeper at the pool's shutdown."""
    from tissue_sim_ros.analysis.jobs import WorkerPool
    t0 = time.monotonic()
    with pytest.raises(TypeError):
        if own_pool:
            with WorkerPool(2) as pool:
                run_jobs(time.sleep, [60.0, 'not a number'], pool=pool, quiet=True)
        else:
            run_jobs(time.sleep, [60.0, 'not a number'], workers=2, quiet=True)
    assert time.monotonic() - t0 < 30.0
