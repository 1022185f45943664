"""The rod and the shaft's points in the tissue solved together (engine/needle/rod_coupling.py
and its compiled step): a rod that cannot bend gives the rigid needle's wrench, the compiled
steps are the general path to the last bit, the rod keeps its length."""
import numpy as np

from support.flexible import SPEED, phantom
from tissue_sim_ros.analysis.steering import insert_path
from tissue_sim_ros.bench.steering import needle_sets


def test_a_very_stiff_rod_is_the_rigid_needle():
    """The rod and the shaft's points solved together reduce to the rigid needle's projection when
    the rod cannot bend: the same wrench, within 1 % of its largest value, through the capsule and in."""
    def wrench(*sets):
        scene = phantom(*sets)
        path = insert_path(scene, scene.start_gap_m + 0.008, SPEED)
        return path.force, scene.needle.tip_deflection()
    rigid, _ = wrench('needle.tip.shape=bevel')
    stiff, deflection = wrench('needle.flexible=true', 'needle.young_modulus_pa=1e16')
    assert deflection < 1e-9
    assert np.abs(stiff - rigid).max() < 0.01 * np.abs(rigid).max()


def test_the_flexible_needles_compiled_steps_are_its_general_path_bit_for_bit():
    """The compiled slices and the one-call inside step run the same kernels in the same order
    as the Python calls: the same wrench and shape to the last bit, and they did run."""
    def run(compiled):
        scene = phantom(*needle_sets('20 G nitinol'))
        scene.compiled_substeps = scene.needle.compiled_inside = compiled
        path = insert_path(scene, scene.start_gap_m + 0.006, SPEED)
        return path.force, path.tip, scene.needle.shape(), scene
    compiled, general = run(True), run(False)
    assert compiled[3]._compiled.counts.get(('inside', 0), 0) > 100
    for a, b in zip(compiled[:3], general[:3]):
        assert np.array_equal(a, b)


def test_the_rod_keeps_its_length_in_the_tissue():
    """The rod's segments keep their rest length but for the tube's elastic strain under the axial
    load, at most the axial force over EA (no drift with the steps)."""
    scene = phantom(*needle_sets('20 G nitinol'))
    path = insert_path(scene, scene.start_gap_m + 0.012, SPEED)
    strain = np.linalg.norm(np.diff(scene.needle.shape(), axis=0), axis=1) / scene.needle.rod.h - 1.0
    axial = float(np.abs(path.force[-1] @ path.axis))
    print(f'strain {strain.min():.3g} .. {strain.max():.3g}; axial force over EA {axial / scene.needle.rod.axial:.3g}')
    assert scene.needle.n_points > 3 and axial > 0.1
    assert np.abs(strain).max() <= 1.2 * axial / scene.needle.rod.axial
