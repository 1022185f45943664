"""The plate compression (analysis/charting/compression.py), whose answer is E A strain: the
``compress`` demo tracks it, and the chart's cube gets every model key of the scene."""

import re

import pytest

from tissue_sim_ros.engine.scene.scene import Scene

COARSE = {'mesh.fine_size_m': 0.004, 'mesh.divisions': [5, 5, 4]}


def test_the_plate_compression_cube_gets_every_model_key_of_the_scene():
    """The chart's compression task builds its cube with the scene's builder: the relaxation and
    the precision reach it."""
    from tissue_sim_ros.analysis.charting.compression import scene_block
    scene = Scene.from_file(None, values={**COARSE, 'model.precision': 'float32',
                                          'model.relaxation': [{'relative_modulus': 0.3, 'time_constant_s': 1.0}]})
    block = scene_block(scene, 0.005, divisions=2)
    model = block.simulation.model
    assert model.precision == 'float32' and model.relaxation is not None
    assert model.geometric == scene.model.geometric and model.viscous == scene.model.viscous
    assert block.simulation.dt == pytest.approx(scene.spec['solver']['time_step_safety']
                                               * block.simulation.critical_time_step(), rel=1e-9)


def test_compress_demo_writes_plot_and_tracks_E_A_strain(tmp_path, capsys):
    from tissue_sim_ros.cli import app as cli
    cli.main(['compress', '--out', str(tmp_path), '--strain', '0.03', '--speed-mm-s', '5'])
    assert (tmp_path / 'compression.png').stat().st_size > 10_000
    out = capsys.readouterr().out
    final = float(re.search(r'final reaction ([0-9.]+) N', out).group(1))
    # 0.05 x 0.05 block, 0.03 high, E = 5 kPa: E A strain = 0.375 N at 3 %; slow plate, within 3 %
    assert final == pytest.approx(5e3 * 0.05 * 0.05 * 0.03, rel=0.03)
