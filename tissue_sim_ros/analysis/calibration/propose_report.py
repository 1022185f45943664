"""What ``tissue-sim propose`` writes into ``--out DIR``.

- ``proposed.yaml``: the complete proposed scene (every key), the layers and the command in comments;
- ``propose.json`` (schema ``tissue_sim_ros/propose/1``): ``speed_m_s``, ``repeats``, ``layers`` (per
  layer: ``depth_m``, ``depth_sd_m``, ``depth_min_m``, ``depth_max_m``, ``force_n``, ``force_sd_n``,
  ``force_min_n``, ``force_max_n``, ``drop_n``, ``found``, ``repeats``, ``assisted``, and the scene keys
  set for it), ``values`` (each starting value: ``value``, ``derived`` from the data's feature,
  ``refined`` after the simulation runs), ``runs`` (each refinement run's NRMSE over every sample,
  the values it ran and the features its simulation gave; ``relaxation_scan`` after the run that
  scanned the relaxing part: per part its simulated pause fraction and NRMSE),
  ``nrmse_all_samples`` (the proposal's), ``pre_drops`` (drops told from punctures), ``fits`` (the
  ``--fit`` keys and bounds: ``key``, ``low``, ``high``, ``log``, ``acts_on``, ``text``),
  ``calibrate_command``, ``resolution`` (per layer its ``thickness_m`` along the needle and
  ``elements_across``: that over ``path_edge_m``, the mesh's mean edge along the path), ``warnings``
  (a layer too few elements thick to be told from its neighbours: ``layer_resolution``),
  ``wall_s``, ``outputs``;
- ``propose.md``: the same for a person; ``propose.csv``: a row per layer;
- ``propose.png``: the repeats by depth since contact and by time since contact, their punctures
  (circles) and pre-drops (triangles), each layer's depths (a band over the repeats' range) and
  mean peak force, the proposal's simulation.
"""
from __future__ import annotations

import csv
import json
import math
from pathlib import Path

import numpy as np

__all__ = ['SCHEMA', 'dumps', 'write_proposal']

SCHEMA = 'tissue_sim_ros/propose/1'

#: the starting values' names -> the scene key each sets (layer k's with [k])
KEYS = {'modulus_pa': 'regions[{k}].young_modulus_pa', 'rupture_n': 'regions[{k}].membrane.rupture_force_n',
        'friction_n_per_m': 'regions[{k}].friction.insertion_coulomb_n_per_m',
        'cutting_n': 'regions[{k}].cutting_force_n', 'retraction_n': 'regions[{k}].friction.retraction_constant_n',
        'boundary_m': 'regions[{k}].select.below_z_m (depth below the top)'}


def _key_of(name: str) -> str:
    if '[' in name:
        base, k = name[:-1].split('[')
        return KEYS[base].format(k=k)
    return {'relaxing': 'model.relaxation[0].relative_modulus',
            'relax_time_s': 'model.relaxation[0].time_constant_s'}[name]


def _plot(path, proposal) -> None:
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    from tissue_sim_ros.analysis.compare.force_events import PRE_DROP, detect_drops
    comparisons = proposal['study']['comparisons']
    fig, axes = plt.subplots(1, 2, figsize=(12, 4.4))
    for by, ax in zip(('depth', 'time'), axes):
        for n, c in enumerate(comparisons):
            x = c.travel_since_contact_m * 1e3 if by == 'depth' else c.time_since_contact_s
            ax.plot(x, c.measured_n, color='0.6', lw=0.6, label='repeats' if n == 0 else None)
            for p in c.measured_punctures:
                ax.plot(x[p.index], p.force_n, 'o', mfc='none', color='0.25', ms=5)
            for p in detect_drops(c.travel_since_contact_m, c.measured_n):
                if p.kind == PRE_DROP:
                    shown = 'pre-drop' in ax.get_legend_handles_labels()[1]
                    ax.plot(x[p.index], p.force_n, 'v', color='C1', ms=6, label=None if shown else 'pre-drop')
            if n == 0:
                ax.plot(x, c.simulated_n, color='C3', lw=1.2, label='proposal (simulated)')
        if by == 'depth':
            for k, layer in enumerate(proposal['layers']):
                low, high = layer.depth_range_m
                ax.axvspan(low * 1e3, max(high, low + 1e-5) * 1e3, color=f'C{k % 8}', alpha=0.2)
                ax.errorbar([layer.depth_m * 1e3], [layer.force_n], xerr=[layer.depth_sd_m * 1e3],
                            yerr=[layer.force_sd_n], fmt='s', color=f'C{k % 8}', ms=5, capsize=3,
                            label=f'layer {k}: {layer.depth_m * 1e3:.1f} mm, {layer.force_n:.2f} N')
        ax.set_xlabel('depth since contact [mm]' if by == 'depth' else 'time since contact [s]')
        ax.set_ylabel('axial force [N]')
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, loc='best')
    fig.suptitle(f"proposal: {len(proposal['layers'])} layer(s) from {len(comparisons)} repeat(s); NRMSE "
                 f"{proposal['nrmse_all_samples']:.3f} over every sample", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def write_proposal(out: Path, proposal: dict, *, data_spec, scene_file, sets) -> dict:
    """Write every output (module docstring); the report dict."""
    from tissue_sim_ros.engine.scene.scene import scene_yaml
    out.mkdir(parents=True, exist_ok=True)
    names = ('proposed.yaml', 'propose.json', 'propose.md', 'propose.csv', 'propose.png')
    outputs = {name: str(out / name) for name in names}
    fits = proposal['fits']
    command = (f'tissue-sim calibrate --data-spec {data_spec} --scene {out / "proposed.yaml"} '
               + ' '.join(f'--fit {f["text"]}' for f in fits) + f' --out {out.parent / "calibrate"}')
    layers = []
    for k, layer in enumerate(proposal['layers']):
        region = proposal['spec']['regions'][k]
        layers.append(dict(layer.as_dict(), region=region['name'], select=region['select'],
                           rupture_force_n=region['membrane']['rupture_force_n'],
                           young_modulus_pa=region['young_modulus_pa'], cutting_force_n=region['cutting_force_n']))
    values = {name: {'key': _key_of(name), 'value': proposal['values'][name], 'derived': derived[0],
                     'how': derived[1]} for name, derived in proposal['derived'].items()}
    report = {'schema': SCHEMA, 'data_spec': data_spec, 'scene': str(scene_file or 'the packaged default'),
              'sets': list(sets), 'speed_m_s': proposal['speed_m_s'], 'repeats': len(proposal['trials']),
              'layers': layers, 'values': values, 'runs': proposal['runs'],
              'nrmse_all_samples': proposal['nrmse_all_samples'], 'pre_drops': proposal['pre_drops'],
              'fits': fits, 'calibrate_command': command, 'resolution': proposal['resolution'],
              'path_edge_m': proposal['path_edge_m'], 'warnings': proposal['warnings'], 'wall_s': proposal['wall_s'],
              'outputs': outputs}
    header = ['A layered scene proposed by tissue-sim propose from the data (every key; `tissue-sim scene-keys`).',
              f'data: {data_spec}; base scene: {scene_file or "the packaged default"}'
              + (f' with {" ".join("--set " + s for s in sets)}' if sets else ''),
              f"{len(layers)} layer(s) (depth since contact, peak force; mean +- s.d. over "
              f"{len(proposal['trials'])} repeat(s)):"]
    header += [f"  layer {k}: {l['depth_m'] * 1e3:.2f} +- {l['depth_sd_m'] * 1e3:.2f} mm, "
               f"{l['force_n']:.3f} +- {l['force_sd_n']:.3f} N" for k, l in enumerate(layers)]
    header += [f"NRMSE over every sample {proposal['nrmse_all_samples']:.4f}; calibrate it with:", '  ' + command]
    (out / 'proposed.yaml').write_text(scene_yaml(proposal['spec'], proposal['base_dir'], header))
    (out / 'propose.json').write_text(dumps(report))
    (out / 'propose.md').write_text(_markdown(report))
    with (out / 'propose.csv').open('w', newline='') as handle:
        columns = ['layer', 'region', 'depth_m', 'depth_sd_m', 'depth_min_m', 'depth_max_m', 'force_n', 'force_sd_n',
                   'drop_n', 'found', 'repeats', 'assisted', 'young_modulus_pa', 'rupture_force_n', 'cutting_force_n']
        writer = csv.DictWriter(handle, fieldnames=columns, extrasaction='ignore')
        writer.writeheader()
        for k, layer in enumerate(layers):
            writer.writerow(dict(layer, layer=k))
    _plot(out / 'propose.png', proposal)
    return report


def _markdown(report) -> str:
    def mm(value):
        return 'n/a' if value is None else f'{value * 1e3:.2f}'
    lines = ['# Proposed layers', '', f"Data: {report['data_spec']}; {report['repeats']} repeat(s) at "
             + ('unknown speed' if report['speed_m_s'] is None else f"{report['speed_m_s'] * 1e3:g} mm/s")
             + f"; base scene {report['scene']}.", '',
             '| layer | depth [mm] | s.d. [mm] | range [mm] | peak [N] | s.d. [N] | drop [N] | repeats with it | select |',
             '|---|---|---|---|---|---|---|---|---|']
    for k, l in enumerate(report['layers']):
        found = f"{l['found']} of {l['repeats']}" + (f" ({l['assisted']} found by the others)" if l['assisted'] else '')
        lines.append(f"| {k} | {mm(l['depth_m'])} | {mm(l['depth_sd_m'])} | {mm(l['depth_min_m'])}-"
                     f"{mm(l['depth_max_m'])} | {l['force_n']:.3f} | {l['force_sd_n']:.3f} | {l['drop_n']:.3f} | "
                     f"{found} | `{l['select']}` |")
    lines += ['', f"Pre-drops told from punctures: {report['pre_drops']}.", '',
              '| value | scene key | from the data | proposed | how |', '|---|---|---|---|---|']
    for name, v in report['values'].items():
        lines.append(f"| {name} | `{v['key']}` | {v['derived']:.5g} | {v['value']:.5g} | {v['how']} |")
    lines += ['', 'Refinement (each run a simulation on the median repeat\'s motion, each value moved by what '
              'its feature missed):', '', '| run | NRMSE over every sample |', '|---|---|']
    lines += [f"| {r['run']} | {r['nrmse_all_samples']:.4f} |" for r in report['runs']]
    for r in report['runs']:
        if r.get('relaxation_scan'):
            lines += ['', f"After run {r['run']}, the relaxation scan (each a simulation with that relaxing part; the "
                      f"data's pause relaxes {report['values']['relaxing']['derived']:.4f} of its force):", '',
                      '| relaxing part | simulated pause relaxes | NRMSE over every sample |', '|---|---|---|']
            lines += [f"| {row['relaxing']:.2f} | {row['simulated_fraction']:.4f} | {row['nrmse_all_samples']:.4f} |"
                      for row in r['relaxation_scan']]
    lines += ['', f"Layers along the needle, in the mesh's elements ({report['path_edge_m'] * 1e3:.2f} mm mean edge "
              'there): ' + ', '.join(f"layer {k} {r['thickness_m'] * 1e3:.1f} mm, {r['elements_across']:.1f}"
                                     for k, r in enumerate(report['resolution'])) + '.']
    lines += [f'- warning: {w}' for w in report['warnings']]
    lines += ['', f"The proposal: NRMSE {report['nrmse_all_samples']:.4f}; {report['wall_s']:.1f} s.", '',
              '## Calibrate it', '', '| --fit | acts on |', '|---|---|']
    lines += [f"| `{f['text']}` | {f['acts_on']} |" for f in report['fits']]
    lines += ['', '```bash', report['calibrate_command'], '```']
    return '\n'.join(lines) + '\n'


def _json(value):
    if isinstance(value, dict):
        return {str(k): _json(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_json(v) for v in value]
    if isinstance(value, (float, np.floating)):
        return float(value) if math.isfinite(value) else None
    if isinstance(value, np.integer):
        return int(value)
    return value


def dumps(value) -> str:
    """``value`` as indented JSON: numpy numbers as plain ones, NaN and inf as null."""
    return json.dumps(_json(value), indent=2)
