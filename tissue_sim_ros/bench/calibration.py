"""Benchmark of ``tissue-sim calibrate``: 6 keys over 3 speeds of the default scene.

``tissue-sim bench calibration [--out DIR] [--jobs N]``

The data: the default scene (13872 tetrahedra) with a retraction plateau added, inserted from
1 mm above the surface to 18 mm past it at 1, 2 and 3 mm/s, a 0.5 s hold and back, two repeats
each with 5 mN of noise (:mod:`~tissue_sim_ros.analysis.synthetic_study`). The calibration
starts 30-40 % off on six keys (stiffness, the exponential law's amplitude, the capsule's
rupture force, the cutting force, the insertion friction per length, the retraction plateau),
runs the staged start on a coarse version of the scene (3 mm cells near the needle, 3630
tetrahedra), then on the default one re-fits the loading's keys and finishes with that scene's own
Jacobian (:mod:`~tissue_sim_ros.analysis.calibration.fine`). Printed: wall time, evaluations
and simulations per minute, each key against its truth, the fit NRMSE against the noise floor.
"""
from __future__ import annotations

import time
from pathlib import Path

TRUTH = {'regions[0].young_modulus_pa': 22000.0, 'model.physical.mu_amplitude': 0.5,
         'regions[0].membrane.rupture_force_n': 1.4, 'regions[0].cutting_force_n': 0.94,
         'regions[0].friction.insertion_coulomb_n_per_m': 10.57, 'regions[0].friction.retraction_constant_n': 0.3}
START = {'regions[0].young_modulus_pa': 15000.0, 'model.physical.mu_amplitude': 0.7,
         'regions[0].membrane.rupture_force_n': 1.9, 'regions[0].cutting_force_n': 0.6,
         'regions[0].friction.insertion_coulomb_n_per_m': 15.0, 'regions[0].friction.retraction_constant_n': 0.2}
FITS = ['regions[0].young_modulus_pa=5000:80000:log', 'model.physical.mu_amplitude=0:2',
        'regions[0].membrane.rupture_force_n=0.3:3', 'regions[0].cutting_force_n=0.1:2',
        'regions[0].friction.insertion_coulomb_n_per_m=1:100:log', 'regions[0].friction.retraction_constant_n=0:2']
COARSE = ['mesh.fine_size_m=0.003', 'mesh.divisions=[6,6,5]']
#: the data's needle starts 1 mm above the surface (the default scene's 9 mm minus 8)
DATA_START = ['needle.initial_position_m=[0.0, 0.0, 0.151]']


def _sets(values: dict) -> list[str]:
    return [f'{key}={value!r}' for key, value in values.items()]


def main(*, out='out/bench_calibration', jobs=None) -> dict:
    """``tissue-sim bench calibration``: run the benchmark, print its figures."""
    from tissue_sim_ros.analysis.calibration import calibrate as calibration
    from tissue_sim_ros.analysis.synthetic_study import write_synthetic_study
    out = Path(out)
    spec = write_synthetic_study(out / 'data', DATA_START + _sets(TRUTH), [1.0, 2.0, 3.0], travel_m=0.019)
    wall0 = time.perf_counter()
    report = calibration.main(data_spec=spec, fits=FITS, sets=_sets(START), coarse_sets=COARSE,
                              out=out / 'calibration', workers=jobs)
    wall = time.perf_counter() - wall0
    print(f'\ncalibration of {len(FITS)} keys on 3 speeds (default scene, searched on the coarse one): '
          f'{wall:.1f} s wall, {report["evaluations"]} evaluations ({60 * report["evaluations"] / wall:.1f}/min), '
          f'{report["simulations"]} simulations')
    for key, truth in TRUTH.items():
        entry = report['parameters'][key]
        print(f"  {key:48s} {entry['value']:10.5g}  true {truth:8.5g}  ({100 * (entry['value'] / truth - 1):+6.1f} %)"
              f"  start {entry['start']:8.5g}")
    floors = [row['noise_floor_nrmse'] for row in report['fit']['speeds']]
    print(f"fit NRMSE {report['fit']['nrmse_mean']:.4f} (start {report['fit']['nrmse_mean_start']:.4f}); "
          f"noise floors {', '.join(f'{f:.4f}' for f in floors)}")
    return report


if __name__ == '__main__':
    import sys
    sys.exit('this benchmark runs as: tissue-sim bench calibration (tissue-sim bench --help)')
