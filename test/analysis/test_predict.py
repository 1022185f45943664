"""tissue-sim predict (analysis/predict.py): its four files against the engine's own prediction, the
cheapest rung within --max-error, and the path CSV's refusals by line."""

import csv
import json
import math

import numpy as np
import pytest

from support.paths import ROOT
from support.predictions import _down, _scene
from tissue_sim_ros.analysis.predict import main as predict_main, read_path_csv
from tissue_sim_ros.engine.prediction import check_path, predict
from tissue_sim_ros.engine.scene.scene import Scene


def test_predict_command_writes_its_four_files(tmp_path):
    scene = _scene()
    stamps, positions, orientations = _down(scene, 0.0, 2.4)
    path_csv = tmp_path / 'path.csv'
    rows = np.column_stack([stamps, positions, orientations])
    path_csv.write_text('# a comment line\nt_s,x_m,y_m,z_m,qx,qy,qz,qw,note\n' +
                        ''.join(','.join(f'{v:.9g}' for v in row) + ',x\n' for row in rows))
    sets = ['mesh.generator=box', 'mesh.divisions=[6, 6, 4]',
            'targets=[{name: tumour, position_m: [0.002, 0.0, -0.012]}]']
    out = tmp_path / 'out'
    prediction = predict_main(None, path_csv, out, sets=sets, stream=open(tmp_path / 'log.txt', 'w'))
    with open(out / 'predict.csv') as f:
        table = list(csv.DictReader(f))
    assert len(table) == stamps.size
    direct = predict(scene, check_path(stamps, positions, orientations, max_jump_m=0.005), wrench_frame='needle')
    np.testing.assert_allclose([float(r['force_z_n']) for r in table], direct.column('force_z_n'), atol=1e-6)
    summary = json.loads((out / 'predict.json').read_text())
    assert summary['points'] == stamps.size and summary['wrench_frame'] == 'needle'
    assert summary['peak_force_n'] == pytest.approx(np.linalg.norm(prediction.values[:, :3], axis=1).max())
    assert summary['real_time_factor'] > 0 and math.isfinite(summary['real_time_factor'])
    assert (out / 'predict.png').stat().st_size > 10_000
    assert 'answered in' in (out / 'predict.md').read_text()


def test_predict_with_a_max_error_runs_on_the_cheapest_rung_within_it(tmp_path, monkeypatch):
    """--max-error: the rung the ladder's probe measured within it (the probe's errors, cached in
    a directory of the test's; a mass rung here), fewer substeps for the same path, and the answer
    within about that error of the live settings' (the probe is another path: twice it)."""
    from tissue_sim_ros.engine.ladder import DegradationLadder
    from tissue_sim_ros.engine.ladder_probe import probe_errors
    scene = _scene()
    stamps, positions, orientations = _down(scene, 0.0, 2.4)
    path_csv = tmp_path / 'path.csv'
    path_csv.write_text('t,x,y,z,qx,qy,qz,qw\n' + ''.join(','.join(f'{v:.9g}' for v in row) + '\n'
                                                        for row in np.column_stack([stamps, positions, orientations])))
    sets = ['mesh.generator=box', 'mesh.divisions=[10, 10, 8]']       # 4.6 ms: x4 within the rungs' cap
    log = open(tmp_path / 'log.txt', 'w')
    live = predict_main(None, path_csv, tmp_path / 'live', sets=sets, stream=log)
    monkeypatch.setenv('XDG_CACHE_HOME', str(tmp_path / 'cache'))
    cheap = predict_main(None, path_csv, tmp_path / 'cheap', sets=sets, max_error=0.02, stream=log)
    summary = json.loads((tmp_path / 'cheap' / 'predict.json').read_text())
    probed = Scene.from_file(None, sets=sets)
    ladder = DegradationLadder(probed)
    errors = probe_errors(probed, ladder)
    level = max(k for k, e in enumerate(errors) if e <= 0.02)
    assert summary['rung'] == ladder.rungs[level].name and summary['rung_error'] == pytest.approx(errors[level])
    assert ladder.rungs[level].mass_factor > 1 and cheap.substeps < 0.6 * live.substeps
    force = live.column('force_z_n')
    assert np.sqrt(np.mean((cheap.column('force_z_n') - force) ** 2)) < 2 * 0.02 * np.ptp(force)


def test_a_path_csv_without_a_column_or_with_a_word_is_refused_by_line(tmp_path):
    from tissue_sim_ros.errors import DataError
    bad = tmp_path / 'bad.csv'
    bad.write_text('t,x,y,z,qx,qy,qz\n0,0,0,0.159,1,0,0\n')
    with pytest.raises(DataError, match="no column 'qw'"):
        read_path_csv(bad)
    bad.write_text('t,x,y,z,qx,qy,qz,qw\n# rows follow\n0,0,0,0.159,1,0,0,0\n0.1,0,0,deep,1,0,0,0\n')
    with pytest.raises(DataError, match=r"column 'z', row 4: 'deep'"):
        read_path_csv(bad)


def test_the_shipped_candidate_path_starts_at_the_default_needle():
    stamps, positions, orientations = read_path_csv(ROOT / 'config' / 'candidate_path.csv')
    scene_start = [0.0, 0.0, 0.159]
    assert positions[0].tolist() == scene_start and stamps[-1] - stamps[0] == pytest.approx(10.0)
    check_path(stamps, positions, orientations, max_jump_m=0.005,
               start_pose=(np.array(scene_start), np.array([1.0, 0.0, 0.0, 0.0])))
