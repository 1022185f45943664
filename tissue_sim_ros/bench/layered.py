"""Benchmark of ``propose`` and ``calibrate`` on layered tissue: synthetic phantoms, known values.

``tissue-sim bench layered [--out DIR] [--jobs N] [--max-evaluations 110] [--mesh graded|fine] [--layers 2 3]``

The data (:func:`~tissue_sim_ros.analysis.synthetic_study.phantom_scene`, the 'graded' mesh: 5880
tetrahedra, a 3.3 mm cell around the needle's axis so that the force follows the moduli smoothly;
or the 'fine' one, 1.65 mm there): the two-layer phantom, five repeats at each of 1, 2 and 3 mm/s,
inserted 25 mm past the surface (``TRAVEL_M``), a 5 s pause, retracted; 5 mN of noise; each repeat
draws its layers' rupture forces (0.2 N) and the deep boundary's depth (0.5 mm) from the phantom's
spread. The three-layer phantom the same way. Then:

1. ``propose`` on each phantom's 2 mm/s repeats from a one-layer base (15 kPa, no relaxation):
   its time, the layers it finds against the punctures the simulator made (their depth since
   contact: mean and standard deviation over the repeats);
2. ``calibrate`` of each proposal with 8 keys on the five 2 mm/s repeats, ``--max-evaluations``,
   the 1 and 3 mm/s repeats held out; the two-layer one: both moduli, both rupture forces, the
   deep layer's boundary, its insertion friction, its retraction pull, the relaxing part of the
   pause; the three-layer one: the three moduli and rupture forces, both deeper boundaries. Its
   time, evaluations and simulations, each key against the truth (nominal, and the mean of the
   repeats' draws for the spread keys), the fit and the held-out NRMSE against each speed's
   noise floor and against reusing the nearest measured speed's mean curve, and what the data
   determines least (the calibration's probe).

Printed; the runs' outputs are kept in ``DIR``.
"""
from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

__all__ = ['main']

#: the phantoms' mesh by default (:data:`~tissue_sim_ros.analysis.synthetic_study.PHANTOM_MESHES`);
#: ``--mesh fine`` puts 2.8 elements across the three-layer phantom's middle layer, not 1.5 (3.7x the cost)
MESH = 'graded'

#: per phantom (its layer count): its directories' prefix and the seed of its first study
PHANTOMS = {2: ('two_layers', 1), 3: ('three_layers', 3)}
#: the needle's travel [m] (1 mm of gap, then past the surface) by mesh and phantom: on 'fine' the
#: outer layer gives way about 3 mm deeper (its elements lock less), and the three-layer phantom's
#: core only past 25 mm (at about 25.5 mm since contact)
TRAVEL_M = {('graded', 2): 0.026, ('graded', 3): 0.026, ('fine', 2): 0.026, ('fine', 3): 0.032}

#: the 8 keys calibrated (the proposal's bounds)
KEYS = ('regions[0].young_modulus_pa', 'regions[1].young_modulus_pa', 'regions[0].membrane.rupture_force_n',
        'regions[1].membrane.rupture_force_n', 'regions[1].select.below_z_m',
        'regions[1].friction.insertion_coulomb_n_per_m', 'regions[1].friction.retraction_constant_n',
        'model.relaxation[0].relative_modulus')
#: the three-layer phantom's 8 keys: the three moduli and rupture forces, both deeper boundaries
KEYS_3 = ('regions[0].young_modulus_pa', 'regions[1].young_modulus_pa', 'regions[2].young_modulus_pa',
          'regions[0].membrane.rupture_force_n', 'regions[1].membrane.rupture_force_n',
          'regions[2].membrane.rupture_force_n', 'regions[1].select.below_z_m', 'regions[2].select.below_z_m')


def _truth_of(scene: dict, key: str):
    from tissue_sim_ros.engine.scene.keys import get_key
    return get_key(scene, key)


def _write_base(path: Path, layers: int, mesh: str) -> Path:
    import yaml

    from tissue_sim_ros.analysis.synthetic_study import phantom_scene
    base = phantom_scene(layers, mesh)
    base['regions'] = [{'name': 'tissue', 'select': 'all', 'young_modulus_pa': 15000.0,
                        'friction': {'insertion_static_n_per_m': 200.0}}]
    base['model']['relaxation'] = []
    path.write_text(yaml.safe_dump(base))
    return path


def _made_punctures(spec: Path) -> list[tuple]:
    """Per layer (in order) the mean and standard deviation of the simulator's puncture depths."""
    truth = json.loads((spec.parent / 'truth.json').read_text())
    by_layer: dict = {}
    for trial in truth['trials'].values():
        for k, event in enumerate(trial['punctures']):
            by_layer.setdefault(k, []).append(event['tip_depth_m'])
    return [(float(np.mean(v)), float(np.std(v, ddof=1))) for _, v in sorted(by_layer.items())]


def _calibrate(out: Path, layers: int, fit_spec: Path, held_spec: Path, keys, truth_file: Path, max_evaluations,
               jobs, mesh) -> dict:
    """The calibration of one phantom's proposal (module docstring, 2): printed, its figures."""
    import yaml

    from tissue_sim_ros.analysis.calibration import calibrate as calibration
    proposal = json.loads((out / f'propose_{layers}_layers' / 'propose.json').read_text())
    fits = {f['key']: f['text'] for f in proposal['fits']}
    missing = [key for key in keys if key not in fits]
    if missing:
        print(f"\ncalibrate, {layers}-layer proposal: not run: it proposes {len(proposal['layers'])} layer(s), so it has "
              f"no {', '.join(missing)} to fit (did the needle puncture every layer?)")
        return {'skipped': missing}
    t0 = time.perf_counter()
    result = calibration.main(data_spec=fit_spec, validate_spec=held_spec, scene_file=out / f'propose_{layers}_layers'
                              / 'proposed.yaml', fits=[fits[key] for key in keys], max_evaluations=max_evaluations,
                              workers=jobs, out=out / f'calibrate_{layers}_layers')
    wall = time.perf_counter() - t0
    truth = yaml.safe_load(truth_file.read_text())
    drawn = json.loads((fit_spec.parent / 'truth.json').read_text())['trials'].values()
    print(f'\ncalibrate, {len(keys)} keys of the {layers}-layer proposal on 5 repeats at 2 mm/s ({mesh!r} mesh): '
          f"{wall:.1f} s wall, {result['evaluations']} of {max_evaluations} evaluations, "
          f"{result['simulations']} simulations")
    recovered = {}
    for key in keys:
        entry = result['parameters'][key]
        nominal = float(_truth_of(truth, key))
        values = [t['drawn'][key] for t in drawn if key in t['drawn']]
        mean = float(np.mean(values)) if values else nominal
        if key.endswith('below_z_m'):
            region = key[len('regions['):key.index(']')]
            mean = nominal - float(np.mean([t['drawn'].get(f'regions[{region}].depth_offset_m', 0.0) for t in drawn]))
        recovered[key] = (entry['value'], nominal, mean)
        print(f"  {key:48s} {entry['value']:11.5g}  truth {nominal:9.5g} (repeats' mean {mean:9.5g}): "
              f"{100 * (entry['value'] / mean - 1):+6.1f} %  start {entry['start']:9.5g}")
    for row in result['speeds']:
        print(f"  {row['role']:8s} {row['speed_m_s'] * 1e3:g} mm/s: NRMSE {row['nrmse_calibrated']:.4f} (start "
              f"{row['nrmse_start']:.4f}); noise floor {row['noise_floor_nrmse'] or float('nan'):.4f} "
              f"({(row['nrmse_calibrated'] or 0) / (row['noise_floor_nrmse'] or float('nan')):.2f}x); nearest "
              f"speed's data {row['nearest_speed_nrmse'] or float('nan'):.4f}")
    weakest = result.get('weakest_direction')
    if weakest:
        print('  least determined: ' + ', '.join(f"{key} {entry['minus']:.4g} to {entry['plus']:.4g}"
                                                 for key, entry in weakest['keys'].items())
              + f"; fit NRMSE {' / '.join(f'{n:.4f}' for n in weakest['nrmse'])}, objective "
              f"{' / '.join(f'{n:.4g}' for n in weakest['objective'])}, the ends worse by "
              f"{' and '.join(f'{t:.1f}' for t in weakest['worse_t'])} standard errors over the repeats: "
              f"{'told apart' if weakest['told_apart'] else 'not told apart'}")
    return {'wall_s': wall, 'evaluations': result['evaluations'], 'simulations': result['simulations'],
            'recovered': recovered, 'speeds': result['speeds'], 'weakest_direction': weakest}


def main(*, out='out/bench_layered', jobs=None, max_evaluations=110, mesh=MESH, layers=(2, 3)) -> dict:
    """``tissue-sim bench layered``: run the benchmark on the phantoms with ``layers`` layers, print its
    figures."""
    import yaml

    from tissue_sim_ros.analysis.calibration import propose
    from tissue_sim_ros.analysis.synthetic_study import phantom_scene, write_layered_study
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    figures = {}
    specs = {}
    wall0 = time.perf_counter()
    for count in layers:
        truth = out / f'truth_{count}_layers.yaml'
        truth.write_text(yaml.safe_dump(phantom_scene(count, mesh)))
        name, seed = PHANTOMS[count]
        specs[count] = [write_layered_study(out / f'{name}_{label}', [], speeds, scene_file=truth, workers=jobs,
                                            travel_m=TRAVEL_M[mesh, count], seed=seed + k)
                        for k, (label, speeds) in enumerate((('2mm_s', [2.0]), ('1_3mm_s', [1.0, 3.0])))]
    print(f'data: {15 * len(layers)} trials in {time.perf_counter() - wall0:.0f} s (a study made before from the same '
          'inputs is kept)')
    for count in layers:
        t0 = time.perf_counter()
        report = propose.main(data_spec=specs[count][0], scene_file=_write_base(out / f'base_{count}.yaml', count, mesh),
                              out=out / f'propose_{count}_layers', workers=jobs)
        wall = time.perf_counter() - t0
        made = _made_punctures(specs[count][0])
        found = [(l['depth_m'], l['depth_sd_m']) for l in report['layers']]
        print(f'\npropose, {count}-layer phantom: {len(found)} layer(s) found (made {len(made)}) in {wall:.1f} s; '
              f'proposal NRMSE {report["nrmse_all_samples"]:.4f} over every sample')
        for k, ((depth, sd), (true_depth, true_sd)) in enumerate(zip(found, made)):
            print(f'  layer {k}: {depth * 1e3:6.2f} +- {sd * 1e3:.2f} mm; the simulator punctured it at '
                  f'{true_depth * 1e3:6.2f} +- {true_sd * 1e3:.2f} mm ({(depth - true_depth) / max(true_sd, 1e-9):+.2f} s.d.)')
        figures[f'propose_{count}'] = {'wall_s': wall, 'layers': len(found), 'made': len(made), 'found': found,
                                       'punctured': made, 'nrmse': report['nrmse_all_samples']}
    for count in layers:
        figures[f'calibrate_{count}'] = _calibrate(out, count, *specs[count], KEYS if count == 2 else KEYS_3,
                                                   out / f'truth_{count}_layers.yaml', max_evaluations, jobs, mesh)
    (out / 'figures.json').write_text(json.dumps(figures, indent=2, default=float))
    return figures


if __name__ == '__main__':
    import sys
    sys.exit('this benchmark runs as: tissue-sim bench layered (tissue-sim bench --help)')
