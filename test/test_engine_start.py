"""The node's engine thread before the first tick (ros.loop.engine_thread): the node is still
starting (its set-up holds the GIL for tenths of a second), so the engine simulates nothing then,
owes nothing, and warns of no lag; from the first tick on it follows the clock."""
import time

from tissue_sim_ros.engine.driver import SimulationDriver
from tissue_sim_ros.engine.scene.scene import Scene
from tissue_sim_ros.ros.loop.engine_thread import EngineLoop
from tissue_sim_ros.ros.loop.pose_input import PoseInput, PoseInputLimits


def test_nothing_is_simulated_or_owed_before_the_first_tick():
    scene = Scene.from_file(None, values={'mesh.fine_size_m': 0.004, 'mesh.divisions': [5, 5, 4]})
    driver = SimulationDriver(scene, wrench_frame='needle', on_divergence='reset')
    logged = []
    engine = EngineLoop(driver, PoseInput(PoseInputLimits(), reference_pose=scene.needle_pose), period_s=0.02,
                        now_ns=time.time_ns, decode=None, log_once=lambda *a: logged.append(a),
                        log=lambda *a: logged.append(a))
    engine.start()
    try:
        started = time.perf_counter()
        while time.perf_counter() - started < 0.6:     # a start-up's worth of GIL-heavy work
            sum(i * i for i in range(20_000))
        assert engine.advances == 0 and driver.dropped_s == 0.0 and scene.time == 0.0
        assert not logged                              # no lag warned of, nothing at all
        for _ in range(15):
            engine.tick()
            time.sleep(0.02)
        deadline = time.monotonic() + 10.0
        while engine.stepped_s < 0.1:                  # the engine follows the clock once ticking
            assert time.monotonic() < deadline, f'simulated {engine.stepped_s} s after 15 ticks'
            time.sleep(0.01)
    finally:
        engine.stop()
