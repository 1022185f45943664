"""A substep as the force kernel and one compiled call (engine.compiled_substep) is the general
substep bit for bit, in every phase it covers and at the steps it hands back; the watchdog trips
at the same step with the same message, at the same limit."""

import numpy as np
import pytest

from support.scenes import COARSE_FAR
from tissue_sim_ros.analysis.insertion import run_insertion
from tissue_sim_ros.engine.compiled import substeps as compiled_substep
from tissue_sim_ros.engine.compiled.call import compiled_address
from tissue_sim_ros.engine.scene.scene import Scene
from tissue_sim_ros.errors import SimulationDiverged

#: a capsule, then a second layer with its own membrane under a plane (the apex's layer decided
#: in the compiled call) and a box region with other laws below it
LAYERS = {'regions': [
    {'name': 'capsule', 'young_modulus_pa': 20000.0, 'poisson_ratio': 0.45, 'cutting_force_n': 0.05,
     'membrane': {'criterion': 'force', 'rupture_force_n': 0.4}},
    {'name': 'deeper', 'select': {'below_z_m': -0.006}, 'young_modulus_pa': 30000.0, 'poisson_ratio': 0.45,
     'cutting_force_n': 0.08, 'membrane': {'criterion': 'force', 'rupture_force_n': 0.3}},
    {'name': 'core', 'select': {'box_m': [[-0.01, -0.01, -0.04], [0.01, 0.01, -0.009]]},
     'young_modulus_pa': 25000.0, 'poisson_ratio': 0.45, 'cutting_force_n': 0.03}]}


def _run(sets, compiled, overrides=None, speed=0.005, depth=0.014):
    """(scene, insertion result, the step counts at which the watchdog checked the energy)."""
    scene = Scene.from_file(sets=COARSE_FAR + sets, **(overrides or {}))
    scene.compiled_substeps = compiled
    checked, note = [], scene.simulation.note_safeguarded

    def recorded():          # at each energy-check step that passed, either path
        checked.append(scene.simulation.step_count)
        return note()
    scene.simulation.note_safeguarded = recorded
    result = run_insertion(scene, speed, scene.start_gap_m + depth, hold_s=0.1, tick=0.02)
    return scene, result, checked


#: the membrane punctured by the work done since contact (about 2/3 of the force criterion's)
ENERGY = ['regions[0].membrane.criterion=energy', 'regions[0].membrane.toughness_j_per_m2=3000',
          'regions[0].membrane.rate_exponent=0.2']


@pytest.mark.parametrize('tip, overrides, extra', [('bevel', None, []), ('flat', None, []), ('conical', LAYERS, []),
                                                   ('bevel', None, ENERGY)],
                         ids=['bevel', 'flat', 'conical-layers', 'bevel-energy'])
def test_compiled_substeps_are_the_general_substeps_bit_for_bit(tip, overrides, extra):
    """Approach, puncture(s), insertion, hold, retraction and out again: the wrench at every tick,
    the phases, the punctures, the tissue state and the work put in are the same to the last bit
    with the compiled substeps and without; the compiled slices ran most steps, outside and
    inside, and handed steps back (the surface met, new shaft points, layers, released points);
    a sharp tip's contact with the membrane too (samples touching, the puncture)."""
    sets = [f'needle.tip.shape={tip}'] + extra
    compiled, fast, checked = _run(sets, True, overrides)
    general, slow, checked_general = _run(sets, False, overrides)
    assert checked == checked_general and len(checked) >= fast.steps // compiled.simulation.check_interval
    assert np.array_equal(fast.force, slow.force) and np.array_equal(fast.torque, slow.torque)
    assert fast.phase == slow.phase and {'approach', 'contact', 'inserted', 'retracting'} <= set(fast.phase)
    assert compiled.puncture_events == general.puncture_events and len(compiled.puncture_events) >= 1
    for name in ('displacement', 'velocity', 'internal_force'):
        assert np.array_equal(getattr(compiled.simulation, name), getattr(general.simulation, name)), name
    assert compiled.simulation.input_work == general.simulation.input_work
    assert compiled.simulation.step_count == general.simulation.step_count == fast.steps
    assert compiled.simulation.time == general.simulation.time
    counts = compiled._compiled.counts
    done = counts.get(('approach', compiled_substep.DONE), 0) + counts.get(('inside', compiled_substep.DONE), 0)
    assert done > 0.6 * fast.steps, counts
    assert sum(n for (mode, what), n in counts.items() if what == 'checked') > 0.6 * len(checked), counts
    assert counts.get(('approach', compiled_substep.TAIL), 0) >= 1
    assert counts.get(('inside', compiled_substep.TAIL), 0) >= 3
    if tip != 'flat':
        assert counts.get(('contact', compiled_substep.DONE), 0) > 100, counts
        assert counts.get(('contact', compiled_substep.TAIL), 0) >= 1           # the puncture
        if tip == 'bevel':      # its samples touch one by one (a cone's at once, before the slices)
            assert counts.get(('contact', compiled_substep.ENGAGED), 0) >= 1
    if overrides is not None:
        assert [e['region'] for e in compiled.puncture_events] == ['capsule', 'deeper']


@pytest.mark.parametrize('phase_depth', [0.0, 0.012], ids=['outside', 'inside'])
def test_the_watchdog_trips_at_the_same_step_either_way(phase_depth):
    """A step far past the critical one diverges: the compiled substep stops at the same step, with
    the same message and the same state as Simulation.step (needle outside and inside)."""
    outcomes = []
    for compiled in (True, False):
        scene = Scene.from_file(sets=COARSE_FAR)
        scene.compiled_substeps = compiled
        p, q = scene.needle_pose
        axis = scene.needle.axis
        depth = scene.start_gap_m + phase_depth
        for k in range(1, 41):
            scene.advance(0.02, p + axis * depth * min(1.0, k / 30), q)
        assert scene.phase == ('approach' if phase_depth == 0.0 else 'inserted')
        sim = scene.simulation
        sim.dt *= 2.5
        with pytest.raises(SimulationDiverged) as caught:
            for _ in range(200):
                scene.advance(0.02, p + axis * depth, q)
        outcomes.append((sim.step_count, str(caught.value), sim.displacement.copy(), sim.input_work,
                         scene.needle.position.copy()))
    (steps, message, u, work, position), (steps2, message2, u2, work2, position2) = outcomes
    assert steps == steps2 and message == message2 and 'energy grew without input' in message
    assert np.array_equal(u, u2, equal_nan=True) and work == work2 and np.array_equal(position, position2)


@pytest.mark.parametrize('depth, phase', [(0.0015, 'contact'), (0.012, 'inserted')])
def test_a_failed_energy_check_trips_at_the_same_step_either_way(depth, phase):
    """With the energy limit set to a fifth of the strain energy the tissue holds (the kinetic energy
    far below it), a slow push and a small load on every node, the first energy-check step fails: the compiled slice ends there, and the step,
    the message, the state and the needle's pose are Simulation.step's."""
    outcomes = []
    for compiled in (True, False):
        scene = Scene.from_file(sets=COARSE_FAR + ['needle.tip.shape=bevel'])
        scene.compiled_substeps = compiled
        p, q = scene.needle_pose
        axis = scene.needle.axis
        for k in range(1, 41):
            scene.advance(0.02, p + axis * (scene.start_gap_m + depth) * min(1.0, k / 30), q)
        assert scene.phase == phase
        sim = scene.simulation
        kinetic, strain = sim.energy()
        assert 0.0 < 1e3 * kinetic < strain
        sim.reference_energy = (0.2 * strain - sim.energy_floor) / sim.energy_limit_factor() - max(sim.input_work, 0.0)
        sim.external_forces[:, 2] = -1e-5                 # a load whose work the step puts in
        step = sim.step_count
        with pytest.raises(SimulationDiverged) as caught:
            for k in range(1, 11):
                scene.advance(0.02, p + axis * (scene.start_gap_m + depth + 2e-5 * k), q)
        assert sim.step_count - step <= sim.check_interval
        outcomes.append((sim.step_count, str(caught.value), sim.displacement.copy(), sim.velocity.copy(),
                         sim.input_work, sim.kinetic_energy, scene.needle.position.copy(), scene.needle.tip.copy()))
        if compiled:
            assert sum(n for (mode, what), n in scene._compiled.counts.items() if what == compiled_substep.CHECK) == 1
    first, second = outcomes
    assert first[0] == second[0] and first[1] == second[1] and 'kinetic + strain energy' in first[1]
    assert all(np.array_equal(a, b) for a, b in zip(first[2:], second[2:]))


def test_the_compiled_energy_check_is_the_simulations():
    """_energy_check_fails decides as Simulation.watch(bad, None) and _check_energy raise: a total
    energy 1e-12 below and above the limit, work put in below and above zero, a non-finite
    energy, bad components, inverted elements refused or let through."""
    scene = Scene.from_file(sets=COARSE_FAR)
    sim = scene.simulation
    scene.advance(0.01, *scene.needle_pose)
    for work_in, step_work in ((-2e-3, 1e-4), (0.0, 0.0), (3e-2, -1e-3), (5.0, 2e-3)):
        for allow in (False, True):
            sim.allow_inverted = allow
            sim.input_work = work_in + step_work
            limit = sim._energy_limit()
            watch = np.array([sim.energy_limit_factor(), sim.reference_energy, sim.energy_floor,
                              float(sim.refuses_inverted())])
            cases = [(0.3 * limit, limit * 0.7 * (1 - 1e-12), 0, 0), (0.3 * limit, limit * 0.7 * (1 + 1e-12), 0, 0),
                     (0.1 * limit, np.inf, 0, 0), (0.1 * limit, np.nan, 0, 0), (0.1 * limit, 0.1 * limit, 0, 2),
                     (0.1 * limit, 0.1 * limit, 3, 0)]
            for kinetic, strain, inverted, bad in cases:
                sim.kinetic_energy = kinetic
                try:
                    sim.watch(bad, None)
                    sim._check_energy(strain, inverted)
                    raised = False
                except SimulationDiverged:
                    raised = True
                assert compiled_substep._energy_check_fails(kinetic, strain, inverted, bad, step_work,
                                                            np.array([work_in]), watch) == raised
            assert raised != allow or sim.model.geometric and sim.model.inversion_safeguard


def test_a_function_found_for_other_types_is_refused_and_found_again(monkeypatch):
    """The slice checks the types its three functions were compiled for (engine.compiled_call)
    before it calls them: with every check stale at first (as after an argument changed type),
    each slice is refused, its functions are found again and the run is the general path's, bit
    for bit."""
    found = []

    def stale_first(dispatcher, args, returns):
        address, check = compiled_address(dispatcher, args, returns)
        found.append(dispatcher)
        return address, check + (found.count(dispatcher) == 1)
    monkeypatch.setattr(compiled_substep, 'compiled_address', stale_first)
    compiled, fast, _ = _run(['needle.tip.shape=flat'], True, depth=0.006)
    general, slow, _ = _run(['needle.tip.shape=flat'], False, depth=0.006)
    assert np.array_equal(fast.force, slow.force) and fast.phase == slow.phase
    assert np.array_equal(compiled.simulation.displacement, general.simulation.displacement)
    assert len(found) >= 6 and all(found.count(d) >= 2 for d in found)
    counts = compiled._compiled.counts
    assert counts.get(('approach', compiled_substep.DONE), 0) + counts.get(('inside', compiled_substep.DONE), 0) \
        > 0.5 * fast.steps, counts


def test_a_copied_scene_finds_its_own_compiled_functions():
    """A scene pickled mid-run (as to a prediction worker, another process) carries no address of
    compiled code: its copy gathers its own, and goes on as the original, bit for bit."""
    import pickle
    scene = Scene.from_file(sets=COARSE_FAR + ['needle.tip.shape=bevel'])
    p, q = scene.needle_pose
    axis = scene.needle.axis
    for k in range(1, 16):
        scene.advance(0.02, p + axis * scene.start_gap_m * k / 10, q)
    assert scene._compiled._functions
    copy = pickle.loads(pickle.dumps(scene, protocol=5))
    assert copy._compiled._functions == {} and copy._compiled._calls is None
    for k in range(16, 30):
        for s in (scene, copy):
            s.advance(0.02, p + axis * scene.start_gap_m * k / 10, q)
    assert copy._compiled._functions and copy.phase == scene.phase
    assert np.array_equal(copy.simulation.displacement, scene.simulation.displacement)
    assert np.array_equal(copy.needle.wrench_force, scene.needle.wrench_force)
