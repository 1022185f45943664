"""The step inside the tissue as one compiled call (engine/needle/step.py) is the general path bit
for bit."""

import numpy as np
import pytest

from support.scenes import COARSE_FAR
from tissue_sim_ros.analysis.insertion import run_insertion
from tissue_sim_ros.engine.scene.scene import Scene


@pytest.mark.parametrize('shape, integrator', [('flat', 'explicit'), ('conical', 'explicit'), ('bevel', 'explicit'),
                                               ('bevel', 'implicit')])
def test_the_compiled_inside_step_is_the_general_path_bit_for_bit(shape, integrator, monkeypatch):
    """Inside the tissue the needle's step runs as one compiled call (engine.needle_step); the
    general path runs the same kernels one by one from Python. An insertion through the capsule,
    a hold and the retraction give the same wrench at every tick and the same final tissue state
    either way, and the compiled call did run (on most steps)."""
    from tissue_sim_ros.engine.needle.interaction import NeedleTissue
    calls = []
    compiled_step = NeedleTissue._inserted_step

    def counted(self, *args):
        compiled_step(self, *args)
        # the explicit step sums the work over the nodes it pushed and leaves zeros behind
        calls.append(bool(self.applied_forces.any()))
    monkeypatch.setattr(NeedleTissue, '_inserted_step', counted)

    def run(compiled):
        scene = Scene.from_file(sets=COARSE_FAR + [f'needle.tip.shape={shape}', f'solver.integrator={integrator}'])
        scene.needle.compiled_inside = compiled
        scene.compiled_substeps = False      # (engine/compiled/test_substeps.py: the substep around it)
        speed = 0.005 if integrator == 'explicit' else 0.01          # (an implicit step costs more)
        result = run_insertion(scene, speed, scene.start_gap_m + 0.012, hold_s=0.1, tick=0.02)
        return result, scene.displacement.copy(), scene.simulation.input_work

    compiled, general = run(True), run(False)
    assert len(compiled[0].puncture_events) == 1 and {'inserted', 'retracting'} <= set(compiled[0].phase)
    # (the implicit integrators read the forces after the step: they stay)
    assert len(calls) > compiled[0].steps / 3 and (integrator != 'explicit' or not any(calls))
    assert np.array_equal(compiled[0].force, general[0].force)
    assert np.array_equal(compiled[0].torque, general[0].torque)
    assert compiled[0].phase == general[0].phase
    assert np.array_equal(compiled[1], general[1])
    # the work put in is summed in another order (a loop against numpy's dot)
    assert compiled[2] == pytest.approx(general[2], rel=1e-9)
