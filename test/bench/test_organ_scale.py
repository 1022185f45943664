"""The organ bench's meshes and figures (bench/organ_scale.py): the mesher's own envelope while the
count follows the cell, a looser one where the envelope holds the count above what is asked, each
cached under its own name; the force NRMSE as the RMS over the reference's range."""
import numpy as np
import pytest

from tissue_sim_ros.bench import organ_scale
from tissue_sim_ros.meshing.volume import REGULAR_VOLUME

#: the envelope-bound floor of the stand-in mesher: the organ example's 28000 at its tight envelope
FLOOR = 28_000


def _stand_in_mesher(calls, volume_m3):
    """A mesher whose count is the volume over the regular tetrahedron of the cell, never below
    FLOOR with the default (tight) envelope, as fTetWild did on the organ example."""
    def mesh_surface(surface, out, *, units, cell_m, inclusions, epsilon, threads, echo):
        count = volume_m3 / (REGULAR_VOLUME * cell_m ** 3)
        if epsilon is None:
            count = max(count, FLOOR)
        calls.append((epsilon, cell_m, int(count)))
        return {'tetrahedra': int(count), 'options': {'epsilon': epsilon or 1e-4}, 'seconds': {'mesher': 0.0}}
    return mesh_surface


@pytest.fixture
def stand_in(tmp_path, monkeypatch):
    import tissue_sim_ros.meshing.volume as volume
    from tissue_sim_ros.meshing.organ import write_example_surfaces
    from tissue_sim_ros.meshing.surface import read_surface
    monkeypatch.setenv('XDG_CACHE_HOME', str(tmp_path))
    organ = write_example_surfaces(tmp_path / 'surfaces')['organ']
    calls = []
    monkeypatch.setattr(volume, 'mesh_surface', _stand_in_mesher(calls, read_surface(organ, 'mm').volume))
    return calls


def test_a_small_organ_is_meshed_with_a_looser_envelope_and_a_large_one_with_the_tight_one(stand_in):
    small = organ_scale.organ_mesh(10_000, echo=lambda *a: None)
    # the tight envelope gave 28000 for 10000 (over ENVELOPE_BOUND): no cell correction there, the
    # next envelope at once, whose count follows the cell
    assert [c[0] for c in stand_in] == [None, organ_scale.LOOSER_ENVELOPES[0]]
    assert stand_in[1][2] == pytest.approx(10_000, rel=0.01)
    assert small.name == f'organ-10000-envelope-{organ_scale.LOOSER_ENVELOPES[0]:g}.vtu'
    stand_in.clear()
    large = organ_scale.organ_mesh(50_000, echo=lambda *a: None)
    assert [c[0] for c in stand_in] == [None] and large.name == 'organ-50000.vtu'


def test_force_nrmse_is_the_rms_difference_over_the_reference_range():
    reference = np.array([0.0, 1.0, 2.0, 1.0])
    force = reference + np.array([0.1, -0.1, 0.1, -0.1])
    assert organ_scale.force_nrmse(force, reference) == pytest.approx(0.1 / 2.0)
    assert organ_scale.force_nrmse(reference, reference) == 0.0


def test_a_run_holds_with_no_missed_tick_no_dropped_time_and_room_in_its_budget():
    kept = dict(missed_ticks=0, ladder_level=-1, ladder_changes=-1, dropped_time_s=0.0, budget_use=0.93)
    assert organ_scale.holds(kept)                                  # the ladder off: not reported
    assert organ_scale.holds(dict(kept, ladder_level=0, ladder_changes=0))
    for failed in (dict(missed_ticks=1), dict(dropped_time_s=0.02), dict(budget_use=1.05),
                   dict(ladder_level=1), dict(ladder_level=0, ladder_changes=2)):
        assert not organ_scale.holds(dict(kept, **failed)), failed
