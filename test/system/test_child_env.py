"""A child's environment to import a given source tree (system/child_env.py): the child imports
the package from that tree, whatever the caller's PYTHONPATH holds. Truth: the file the child
imports, and the caller's entries kept after."""
import subprocess
import sys

from tissue_sim_ros.system.child_env import importing_from


def test_a_child_imports_the_package_from_the_tree_it_is_given(tmp_path):
    tree = tmp_path / 'other_revision'
    (tree / 'tissue_sim_ros').mkdir(parents=True)
    (tree / 'tissue_sim_ros' / '__init__.py').write_text('REVISION = "other"\n')
    env = importing_from(tree, {'PYTHONPATH': str(tmp_path / 'elsewhere'), 'PATH': '/usr/bin'})
    assert env['PATH'] == '/usr/bin'
    child = subprocess.run([sys.executable, '-c', 'import sys, tissue_sim_ros\n'
                            'print(tissue_sim_ros.__file__); print(tissue_sim_ros.REVISION)\n'
                            'print(sys.path.index(sys.argv[1]) < sys.path.index(sys.argv[2]))',
                            str(tree), str(tmp_path / 'elsewhere')],
                           env=env, cwd=tmp_path, capture_output=True, text=True, timeout=60)
    assert child.returncode == 0, child.stderr
    imported, revision, before = child.stdout.split()
    assert imported == str(tree / 'tissue_sim_ros' / '__init__.py') and revision == 'other'
    assert before == 'True'                 # the tree first, the caller's entries after


def test_without_a_pythonpath_the_tree_is_all_of_it():
    assert importing_from('/a/tree', {})['PYTHONPATH'] == '/a/tree'
