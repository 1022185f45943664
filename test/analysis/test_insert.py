"""tissue-sim insert (analysis/insert.py): the CSV, plot, figures and report it writes, and a run
without a puncture said so instead of NaN."""

import numpy as np
import pytest

from support.scenes import small_scene


def test_insert_command_writes_the_csv_and_plot(tmp_path):
    import csv
    import json

    import yaml

    from tissue_sim_ros.cli import app as cli
    from tissue_sim_ros.analysis.insertion import CSV_HEADER
    spec = small_scene(region={'membrane': {'criterion': 'force', 'rupture_force_n': 0.1},
                               'cutting_force_n': 0.2}).spec
    scene_file = tmp_path / 'scene.yaml'
    scene_file.write_text(yaml.safe_dump(spec))
    cli.main(['insert', '--scene', str(scene_file), '--speed-mm-s', '10', '--travel-mm', '4',
              '--out', str(tmp_path)])
    with open(tmp_path / 'insert.csv') as f:
        rows = list(csv.reader(f))
    assert tuple(rows[0]) == CSV_HEADER
    phases = [r[-1] for r in rows[1:]]
    assert {'approach', 'contact', 'inserted', 'retracting'} <= set(phases)
    values = np.array([[float(v) for v in r[:-1]] for r in rows[1:]])
    assert np.all(np.isfinite(values)) and values[:, 1].max() == pytest.approx(0.004)
    assert (tmp_path / 'insert.png').stat().st_size > 10_000
    figures = json.loads((tmp_path / 'insert.json').read_text())
    assert figures['peak_axial_force_n'] == pytest.approx(values[:, -1].max(), rel=1e-5)
    assert (tmp_path / 'insert.md').read_text().startswith('# Insertion at 10 mm/s')


def test_insert_without_a_puncture_says_so_instead_of_nan(tmp_path, capsys):
    """The default scene's needle starts 9 mm above the surface: 12 mm of travel indents the
    capsule without puncturing it. The comparison with the bovine liver says there is no puncture
    to compare, not '+nan mm and +nan N off'."""
    from tissue_sim_ros.cli import app as cli
    assert cli.main(['insert', '--travel-mm', '12', '--speed-mm-s', '10', '--set', 'mesh.fine_size_m=0.003',
                     '--set', 'mesh.divisions=[6,6,5]', '--out', str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert 'no puncture in this run' in out and 'nan' not in out
