"""The package's own files (system/paths.py): in a source checkout the shared files are the
checkout's; a file that is nowhere is named where it was looked for. Truth: the repository's own
layout (support.paths.ROOT, found from this test's file)."""
from support.paths import ROOT
from tissue_sim_ros.system import paths


def test_the_package_and_its_shared_files_in_a_checkout():
    assert paths.PACKAGE_DIR == ROOT / 'tissue_sim_ros' and paths.SOURCE_ROOT == ROOT
    for relative in ('config/liver_sample.yaml', 'config/tissue_sim.yaml', 'data/okamura2004_bovine_liver'):
        assert paths.shared_file(relative) == ROOT / relative and (ROOT / relative).exists()


def test_a_file_that_is_nowhere_is_named_where_the_checkout_would_hold_it(monkeypatch):
    monkeypatch.delenv('AMENT_PREFIX_PATH', raising=False)
    assert paths.shared_file('config/no_such_scene.yaml') == ROOT / 'config' / 'no_such_scene.yaml'
