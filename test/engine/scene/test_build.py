"""One builder of a scene's parts (engine/scene/build.py): a time step above the critical one and
keys that cannot go together are refused naming both; a mesh too large for the machine is
refused before it is built."""

import pytest

from tissue_sim_ros.engine.scene.scene import Scene
from tissue_sim_ros.errors import SceneError

COARSE = {'generator': 'box', 'divisions': [6, 6, 4]}

COARSE_VALUES = {'mesh.fine_size_m': 0.004, 'mesh.divisions': [5, 5, 4]}


def test_a_time_step_above_the_critical_step_is_refused_naming_both():
    """3.1x and 5x the stable limit were accepted and the node diverged and reset over and over.
    The refusal names the critical step the simulation estimates itself (independent of the
    check: the same scene with a null step runs at time_step_safety x that estimate)."""
    ok = Scene.from_file(None, mesh=COARSE)
    critical = float(ok.simulation.critical_time_step())
    assert ok.dt == pytest.approx(ok.spec['solver']['time_step_safety'] * critical, rel=1e-12)
    Scene.from_file(None, mesh=COARSE, solver={'time_step_s': 0.99 * critical})  # below: accepted
    for factor in (1.01, 3.1, 5.0):
        with pytest.raises(SceneError) as info:
            Scene.from_file(None, mesh=COARSE, solver={'time_step_s': factor * critical})
        text = str(info.value)
        assert text.startswith(f'solver.time_step_s = {factor * critical!r}')
        assert f'{critical:.4g} s' in text
    with pytest.raises(SceneError, match=r'solver.time_step_safety = 1.5: expected at most 1'):
        Scene.from_file(None, mesh=COARSE, solver={'time_step_safety': 1.5})


def test_keys_that_cannot_go_together_are_refused_naming_both():
    with pytest.raises(SceneError, match="solver.integrator = 'implicit' needs model.precision = float64"):
        Scene.from_file(None, values={**COARSE_VALUES, 'solver.integrator': 'implicit', 'model.precision': 'float32'})


def test_selective_mass_scaling_raises_the_step_of_an_explicit_scene_only():
    """solver.selective_mass_scaling 1.5: the step set by time_step_safety grows at least 1.5-fold
    (the simulation's own estimate, with the masses it added); the implicit integrators refuse it."""
    plain = Scene.from_file(None, mesh=COARSE)
    lifted = Scene.from_file(None, mesh=COARSE, solver={'selective_mass_scaling': 1.5})
    assert lifted.dt >= 1.5 * plain.dt
    assert lifted.dt == pytest.approx(lifted.spec['solver']['time_step_safety']
                                      * lifted.simulation.critical_time_step(), rel=1e-12)
    assert lifted.simulation.selective_added_fraction > 0.0 == plain.simulation.selective_added_fraction
    with pytest.raises(SceneError, match=r"solver.selective_mass_scaling = 1.5 with solver.integrator = 'implicit'"):
        Scene.from_file(None, values={**COARSE_VALUES, 'solver.integrator': 'implicit',
                                      'solver.selective_mass_scaling': 1.5})


def test_a_mistyped_mesh_size_is_refused_at_once_in_bounded_memory():
    """fine_size_m 1e-5 m (a millimetre value written as metres) asks for about 2e7 tetrahedra:
    refused before meshing, naming the key, the estimate and the limit, in a fresh process that
    stays small (before the check existed it grew to 8 GB in 10 s). Its peak is the kernel's
    VmHWM, which starts afresh at exec (getrusage's ru_maxrss keeps the forking parent's: pytest's
    own size late in a suite)."""
    import subprocess
    import sys
    import textwrap
    code = textwrap.dedent('''
        import re, sys, time
        from pathlib import Path
        from tissue_sim_ros.engine.scene.scene import Scene
        from tissue_sim_ros.errors import SceneError
        t = time.perf_counter()
        try:
            Scene.from_file(None, values={'mesh.fine_size_m': 0.00001})
        except SceneError as exc:
            peak = re.search(r'VmHWM:\\s*(\\d+) kB', Path('/proc/self/status').read_text()).group(1)
            print(time.perf_counter() - t, peak, exc)
            sys.exit(0)
        sys.exit('not refused')''')
    done = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    seconds, kilobytes, message = done.stdout.split(' ', 2)
    assert float(seconds) < 1.0 and int(kilobytes) < 600_000
    assert 'mesh.fine_size_m = 1e-05' in message and 'tetrahedra' in message and 'mesh.max_elements' in message


def test_the_mesh_limit_is_a_key_and_a_large_mesh_is_announced(capsys, monkeypatch):
    from tissue_sim_ros.engine.mesh.generators import box_axes, grid_elements
    from tissue_sim_ros.engine.scene import build
    assert grid_elements(box_axes((1, 1, 1), (3, 4, 5))) == 6 * 3 * 4 * 5
    with pytest.raises(SceneError, match=r'about 480 tetrahedra, more than mesh.max_elements = 100'):
        Scene.from_file(None, values={'mesh.generator': 'box', 'mesh.divisions': [4, 4, 5], 'mesh.max_elements': 100})
    monkeypatch.setattr(build, 'ANNOUNCE_ELEMENTS', 100)
    scene = Scene.from_file(None, values={'mesh.generator': 'box', 'mesh.divisions': [4, 4, 5]})
    assert scene.mesh.n_elements == 480
    assert 'building a mesh of about 480 tetrahedra' in capsys.readouterr().err


def test_the_flexible_keys_are_checked():
    with pytest.raises(SceneError, match=r'needle.inner_diameter_m = 0.002: expected less than needle.diameter_m'):
        Scene.from_file(sets=['needle.flexible=true', 'needle.inner_diameter_m=0.002'])
    with pytest.raises(SceneError, match=r'needle.rod_segments = 2.5: expected a whole number'):
        Scene.from_file(sets=['needle.flexible=true', 'needle.rod_segments=2.5'])
