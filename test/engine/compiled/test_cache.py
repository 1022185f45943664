"""First start (engine/compiled/cache.py): where numba's cache goes, what a first start prints, and
which kernels it compiles. Each test runs a fresh Python process, since numba reads its cache
directory once, at import. The cold start's figure is a benchmark: tissue-sim bench cold-start."""

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from support.models import forces_of
from support.paths import ROOT
from tissue_sim_ros.system.child_env import importing_from
from tissue_sim_ros.system.user_cache import sources_key

# compiles one small kernel (about a second): forces.reduce_buffers
SMALL_KERNEL = '''
import numpy as np
from tissue_sim_ros.engine.model import kernels as forces
out = np.zeros((4, 3))
forces.reduce_buffers(np.ones((1, 4, 3)), np.zeros(1, dtype=np.int64), np.full(1, 4, dtype=np.int64), out)
assert (out == 1.0).all()
'''


def run_python(code, env_changes, *args):
    env = {k: v for k, v in os.environ.items() if k not in ('NUMBA_CACHE_DIR', 'XDG_CACHE_HOME')}
    env.update(env_changes)
    env = importing_from(ROOT, env)
    result = subprocess.run([sys.executable, '-c', code, *args], env=env, cwd=str(ROOT),
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, timeout=600)
    assert result.returncode == 0, result.stderr
    return result


def cached_kernels(directory):
    """Names of the numba cache indexes under ``directory`` (one per cached function)."""
    return sorted(p.name for p in Path(directory).rglob('*.nbi'))


def test_cache_goes_to_the_user_cache_directory_and_a_first_start_says_so(tmp_path):
    xdg = tmp_path / 'xdg'
    package_cache = ROOT / 'tissue_sim_ros' / 'engine' / '__pycache__'
    before = {p: p.stat().st_mtime_ns for p in package_cache.glob('*.nbi')} if package_cache.exists() else {}

    first = run_python(SMALL_KERNEL, {'XDG_CACHE_HOME': str(xdg)})
    user_cache = xdg / 'tissue_sim_ros' / 'numba'
    # under the directory of this version of the engine's sources
    keyed = user_cache / sources_key(str(ROOT / 'tissue_sim_ros' / 'engine'))
    assert any(name.startswith('kernels.reduce_buffers') for name in cached_kernels(keyed))
    after = {p: p.stat().st_mtime_ns for p in package_cache.glob('*.nbi')} if package_cache.exists() else {}
    assert after == before, 'numba wrote its cache beside the installed sources'
    assert f'cached in {user_cache}' in first.stderr
    assert 'compiling kernels.reduce_buffers' in first.stderr
    assert 'compiled kernels.reduce_buffers in' in first.stderr

    again = run_python(SMALL_KERNEL, {'XDG_CACHE_HOME': str(xdg)})
    assert 'tissue_sim_ros:' not in again.stderr       # loaded from the cache: nothing to say


def test_numba_cache_dir_of_the_user_moves_the_cache(tmp_path):
    own, xdg = tmp_path / 'own', tmp_path / 'xdg'
    result = run_python(SMALL_KERNEL, {'NUMBA_CACHE_DIR': str(own), 'XDG_CACHE_HOME': str(xdg)})
    assert any(name.startswith('kernels.reduce_buffers') for name in cached_kernels(own))
    assert not xdg.exists()
    assert f'cached in {own}' in result.stderr


def test_a_scene_compiles_the_element_pass_of_its_own_model_and_the_linear_one():
    """The warm-up scene used to add a third (geometric) variant; now the scene's model and the
    linear pass of the critical time step are all (the packaged scene: the full model)."""
    code = '''
from tissue_sim_ros.engine.model import kernels as forces
from tissue_sim_ros.engine.scene.scene import Scene
scene = Scene.from_file()
print(scene.model.geometric, scene.model.physical, scene.model.viscous, forces.element_kernel.cache_info().currsize)
'''
    result = run_python(code, {key: os.environ[key] for key in ('NUMBA_CACHE_DIR', 'XDG_CACHE_HOME')
                               if key in os.environ})
    assert result.stdout.split() == ['True', 'True', 'True', '2']


FORCES_CODE = '''
import sys
import numpy as np
sys.path.insert(0, sys.argv[1])
from support.models import forces_of
state = np.load(sys.argv[2])
for flags in sys.argv[3].split(','):
    np.save(f'{sys.argv[4]}_{flags}.npy', forces_of(tuple(c == '1' for c in flags), state['u'], state['v']))
'''


def random_state(path):
    rng = np.random.default_rng(3)
    np.savez(path, u=1e-4 * rng.normal(size=(64, 3)), v=1e-3 * rng.normal(size=(64, 3)))
    with np.load(path) as arrays:
        return arrays['u'], arrays['v']


@pytest.mark.slow  # two models compiled from an empty cache at once: about 15 s on 2 cores
def test_processes_compiling_different_models_at_once_share_one_cache(tmp_path):
    """What a first start does (engine/compile_cache): processes compile different element-pass
    variants into one cache at the same time. Each model has its own cache index, and a later
    process loads both, compiling nothing, and gets the forces this process gets."""
    u, v = random_state(tmp_path / 'state.npz')
    env = {k: v for k, v in os.environ.items() if k != 'NUMBA_CACHE_DIR'}
    env.update(NUMBA_CACHE_DIR=str(tmp_path / 'cache'), TISSUE_SIM_ROS_COMPILE_PROCESS='1',
               PYTHONPATH=os.pathsep.join([str(ROOT)] + [p for p in [os.environ.get('PYTHONPATH')] if p]))
    models = ('000', '101')           # linear; geometric with viscosity
    code = 'import sys; from tissue_sim_ros.engine.model.tensor_mass import compile_element_pass; ' \
           'compile_element_pass(*(c == "1" for c in sys.argv[1]))'
    processes = [subprocess.Popen([sys.executable, '-c', code, flags], env=env, cwd=str(ROOT),
                                  stderr=subprocess.PIPE, text=True) for flags in models]
    for process in processes:
        assert process.wait(timeout=600) == 0, process.stderr.read()
        process.stderr.close()
    indexes = [name for name in cached_kernels(tmp_path / 'cache') if 'element_kernel' in name]
    assert len(indexes) == 2 and any('kernel_linear' in n for n in indexes), indexes

    later = run_python(FORCES_CODE, {'NUMBA_CACHE_DIR': str(tmp_path / 'cache')}, str(ROOT / 'test'),
                       str(tmp_path / 'state.npz'), ','.join(models), str(tmp_path / 'forces'))
    assert 'compiling element pass' not in later.stderr, later.stderr
    for flags in models:
        here = forces_of(tuple(c == '1' for c in flags), u, v)
        assert np.array_equal(np.load(tmp_path / f'forces_{flags}.npy'), here)


@pytest.mark.slow  # a first start of a geometric model: about 20 s on 2 cores
def test_the_process_of_a_first_start_gets_the_forces_of_every_later_start(tmp_path):
    """A pass compiled in the process that runs it gives forces a few units in the last place
    apart from the cached code's (it calls its thread pass as LLVM optimized it alone); a first
    start compiles it in a separate process and runs the cached code, as every later start."""
    u, v = random_state(tmp_path / 'state.npz')
    first = run_python(FORCES_CODE, {'NUMBA_CACHE_DIR': str(tmp_path / 'cache')}, str(ROOT / 'test'),
                       str(tmp_path / 'state.npz'), '101', str(tmp_path / 'forces'))
    assert 'compiling element pass, geometric_viscous model in a separate process' in first.stderr
    assert 'compiling element pass, geometric_viscous model ...' not in first.stderr
    assert np.array_equal(np.load(tmp_path / 'forces_101.npy'), forces_of((True, False, True), u, v))


def test_every_probed_kernel_is_refused_not_only_the_first():
    """call_compiled_apart probes the cache by refusing the probed kernel's compile. numba ends a
    compile event whose start raised, so a refusal must leave the reporter's nesting depth where it
    was: counted wrongly, the first refusal worked and every later element pass of the process
    (a second model, or a cache made stale by new sources) was compiled here, unseen. Small
    uncached functions stand in for the element passes."""
    from numba import njit
    from tissue_sim_ros.engine.compiled import cache as compile_cache
    for offset in (1.0, 2.0, 3.0):
        probed = njit(lambda x, offset=offset: x + offset)
        found, _ = compile_cache._from_cache(probed, (1.0,), 'float64')
        assert not found and compile_cache.REPORTER.depth == 0
        assert probed(1.0) == 1.0 + offset         # an ordinary call afterwards compiles it
        assert compile_cache.REPORTER.depth == 0
