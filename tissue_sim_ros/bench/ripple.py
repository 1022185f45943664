"""How smooth the axial force is after puncture, printed::

    tissue-sim bench ripple [--scene S] [--set KEY=VALUE]... [--speed-mm-s 3]

The needle goes in at constant speed 40 mm from its start (the default scene: through the
capsule at about 19 mm, then 20 mm of homogeneous liver), sampled every 5 ms. From 3 mm after the
first puncture to 1 mm before the end, a quadratic in travel is fitted to the axial force; the
ripple is the largest deviation from it, in percent of the mean force there (and its RMS), with
the travels of the deepest dips. Measured curves are smooth there; the goal is under 3 %.
"""
from __future__ import annotations


import numpy as np

__all__ = ['measure_ripple', 'main']


def measure_ripple(scene, speed_m_s: float = 0.003, travel_m: float = 0.040, tick_s: float = 0.005) -> dict:
    from tissue_sim_ros.engine.driver import SimulationDriver
    driver = SimulationDriver(scene)
    start, orientation = scene.needle_pose
    axis = scene.needle.axis.copy()
    times = np.arange(1, int(round(travel_m / speed_m_s / tick_s)) + 1) * tick_s
    travel = times * speed_m_s
    force = np.empty(len(times))
    for k in range(len(times)):
        driver.advance(tick_s, start + travel[k] * axis, orientation)
        force[k] = -float(driver.force @ axis)
    events = scene.puncture_events
    if not events:
        raise ValueError('no puncture in the run: nothing to measure after it')
    punctured = float(np.interp(events[0]['time_s'], times, travel))
    window = (travel > punctured + 0.003) & (travel < travel[-1] - 0.001)
    fit = np.polyval(np.polyfit(travel[window], force[window], 2), travel[window])
    deviation = force[window] - fit
    mean = float(force[window].mean())
    dips = travel[window][np.argsort(deviation)[:5]]
    return {'mean_force_n': mean, 'ripple_pct': 100 * float(np.abs(deviation).max()) / mean,
            'rms_pct': 100 * float(np.sqrt(np.mean(deviation ** 2))) / mean,
            'window_mm': (float(travel[window][0] * 1e3), float(travel[window][-1] * 1e3)),
            'first_puncture_travel_mm': punctured * 1e3, 'deepest_dips_mm': (dips * 1e3).tolist()}


def main(*, scene=None, sets=(), speed_mm_s=3.0) -> dict:
    """``tissue-sim bench ripple``: measure on one thread, print the figures."""
    import numba
    from tissue_sim_ros.analysis.charting.auto_keys import load_scene
    numba.set_num_threads(1)
    scene = load_scene(scene, sets=sets)
    scene.model.set_threads(1)
    r = measure_ripple(scene, speed_mm_s * 1e-3)
    print(f"after the first puncture ({r['first_puncture_travel_mm']:.2f} mm), travel "
          f"{r['window_mm'][0]:.1f}-{r['window_mm'][1]:.1f} mm at {speed_mm_s:g} mm/s: mean axial "
          f"force {r['mean_force_n']:.3f} N, ripple {r['ripple_pct']:.2f} % of it (RMS {r['rms_pct']:.2f} %); "
          f"deepest dips at {', '.join(f'{d:.2f}' for d in r['deepest_dips_mm'])} mm (goal: under 3 %)")
    return r


if __name__ == '__main__':
    import sys
    sys.exit('this benchmark runs as: tissue-sim bench ripple (tissue-sim bench --help)')
