"""Synthetic studies with known keys for the calibration tests, and a linear objective whose
optimum numpy finds."""

from pathlib import Path

import numpy as np

from tissue_sim_ros.analysis.calibration import calibrate as calibration
from tissue_sim_ros.analysis.calibration.objective import Objective
from tissue_sim_ros.analysis.synthetic_study import write_synthetic_study

# the tests' own tissue, not the default scene's calibrated values (they move when it is calibrated again)
TISSUE = ['regions[0].friction.insertion_coulomb_n_per_m=10.57']
MESH = ['mesh.generator=box', 'mesh.divisions=[8,8,6]'] + TISSUE
TRUE = {'regions[0].young_modulus_pa': 20000.0, 'regions[0].membrane.rupture_force_n': 0.6,
        'regions[0].cutting_force_n': 0.5}
START = {'regions[0].young_modulus_pa': 13000.0, 'regions[0].membrane.rupture_force_n': 0.85,
         'regions[0].cutting_force_n': 0.33}              # -35 %, +42 %, -34 %
FITS = ['regions[0].young_modulus_pa=5000:50000:log', 'regions[0].membrane.rupture_force_n=0.2:2',
        'regions[0].cutting_force_n=0.1:1.5']
NOISE_N = 0.005

CHEAP_MESH = ['mesh.generator=box', 'mesh.divisions=[6,6,5]', 'regions[0].membrane.criterion=none'] + TISSUE
CHEAP_FITS = ['regions[0].young_modulus_pa=5000:50000:log', 'regions[0].cutting_force_n=0.1:1.5']


def sets(values):
    return [f'{key}={value!r}' for key, value in values.items()]


def write_study(directory: Path, speeds_mm_s, scene_sets, *, travel_m=0.02, repeats=2, seed=1) -> Path:
    return write_synthetic_study(directory, scene_sets, speeds_mm_s, travel_m=travel_m, repeats=repeats,
                                 noise_n=NOISE_N, seed=seed)


def cheap_run(spec, out, **options):
    return calibration.main(data_spec=spec, fits=CHEAP_FITS, sets=CHEAP_MESH + sets(START), out=out,
                            max_evaluations=40, **options)


class _LinearObjective:
    """r(u) = A u - b (+ C u^2, elementwise square, with ``C``): a model whose residuals are
    linear (or quadratic) in the parameters, with the objective interface the search and the
    fine stage use; its first ``loading`` residuals are the loading's (all without it)."""

    def __init__(self, A, b, keys, C=None, loading=None):
        self.A, self.b, self.keys, self.C, self.loading = A, b, keys, C, loading
        self._cache, self.best, self.budget = {}, None, None

    def residuals(self, u):
        u = np.asarray(u)
        return self.A @ u - self.b + (0.0 if self.C is None else self.C @ (u * u))

    @staticmethod
    def _key(u):
        return Objective._key(u)

    @property
    def evaluations(self):
        return list(self._cache.values())

    def values(self, u):
        """The scene values an evaluation records (none here)."""
        return {}

    def evaluate_many(self, us, phases=None):
        from tissue_sim_ros.analysis.calibration.objective import Evaluation
        out = []
        for u in us:
            k = self._key(u)
            if k not in self._cache:
                self._cache[k] = Evaluation(k, self.values(u), self.residuals(u), [], [])
                if self.best is None or self._cache[k].objective < self.best.objective:
                    self.best = self._cache[k]
            out.append(self._cache[k])
        return out

    def evaluate(self, u, phases=None):
        return self.evaluate_many([u])[0]

    def stage_residuals(self, evaluation, phases=None):
        if phases == ('loading',) and self.loading is not None:
            return evaluation.residuals[:self.loading]
        return evaluation.residuals
