"""``tissue-sim bench organ``: the node at organ scale, per model and mesh size.

The organ example (config/organ_example.yaml: the project's organ with a tumour and a vessel, on
springs and a ligament, under gravity, the needle at 25 degrees) is meshed at each asked size
(fTetWild has no element-count target: the ideal edge length comes from the volume, and one
correction by the cube root of the count's ratio lands within about 10 %; meshes cached per
size in the user cache), and each model runs in the node for ``duration_s`` under node-bench
(the scripted insertion along the scene's axis, 15 mm into the tissue and back, at 5 mm/s; the
needle inside for most of the window). A configuration holds 50 Hz when no tick was missed, the
degradation ladder did not step down and no simulated time was dropped: the engine kept real time
with the scene's own settings. The largest mesh that holds per model is the figure; the scene
values of each run (--set) say what it took (the mass scaling, the threshold, float32).
"""
from __future__ import annotations

import json
import tempfile
from pathlib import Path

__all__ = ['MODELS', 'organ_mesh', 'run', 'main']

#: model name -> scene values (the four of the seed paper; the full model with the example's
#: exponential law, viscosity and threshold)
MODELS = {
    'linear': {'model.geometric': False, 'model.physical.law': 'none', 'model.viscosity_mu_pa_s': 0.0},
    'physical': {'model.geometric': False, 'model.viscosity_mu_pa_s': 0.0},
    'geometric': {'model.geometric': True, 'model.physical.law': 'none', 'model.viscosity_mu_pa_s': 0.0},
    'full': {},
}
EXAMPLE = 'config/organ_example.yaml'


def organ_mesh(tetrahedra: int, threads: int = 0, echo=print) -> Path:
    """The organ example meshed at about ``tetrahedra`` elements (module docstring), cached."""
    import numpy as np

    from tissue_sim_ros.meshing.organ import write_example_surfaces
    from tissue_sim_ros.meshing.surface import read_surface
    from tissue_sim_ros.meshing.volume import cell_for_count, mesh_surface
    from tissue_sim_ros.system.user_cache import user_cache_dir
    folder = Path(user_cache_dir('organ_meshes') or tempfile.gettempdir()) / 'organ_scale'
    path = folder / f'organ-{int(tetrahedra)}.vtu'
    if path.is_file():
        return path
    surfaces = write_example_surfaces(folder / 'surfaces')
    inclusions = [('tumour', surfaces['tumour']), ('vessel', surfaces['vessel'])]
    cell = cell_for_count(read_surface(surfaces['organ'], 'mm').volume, tetrahedra)
    for attempt in range(2):
        report = mesh_surface(surfaces['organ'], path, units='mm', cell_m=cell, inclusions=inclusions,
                              threads=threads, echo=lambda *a: None)
        echo(f'organ mesh at {cell * 1e3:.2f} mm: {report["tetrahedra"]} tetrahedra (asked {tetrahedra}), '
             f'mesher {report["seconds"]["mesher"]:.1f} s')
        if abs(report['tetrahedra'] / tetrahedra - 1.0) < 0.15:
            break
        cell *= float(np.cbrt(report['tetrahedra'] / tetrahedra))
    return path


def _variant_scene(mesh: Path, values: dict, sets, folder: Path, name: str) -> Path:
    from tissue_sim_ros.engine.scene.scene import read_scene_keys, scene_yaml
    from tissue_sim_ros.system.paths import shared_file
    example = shared_file(EXAMPLE)
    spec, _, base = read_scene_keys(example, list(sets), {**values, 'mesh.file': str(mesh.resolve())})
    path = folder / f'{name}.yaml'
    path.write_text(scene_yaml(spec, base, header=[f'{EXAMPLE} at {mesh.name}, {name}']))
    return path


def holds(result: dict) -> bool:
    """Whether a node-bench run kept 50 Hz on the scene's own settings (module docstring)."""
    return (result['missed_ticks'] == 0 and result['ladder_level'] == 0 and result['ladder_changes'] == 0
            and result['dropped_time_s'] == 0.0)


def run(sizes=(25_000, 50_000, 100_000), models=tuple(MODELS), sets=(), duration_s=20.0, out=None,
        threads=None, echo=print) -> list[dict]:
    """Every model on every size under node-bench; rows of figures (printed as they come)."""
    from tissue_sim_ros.bench.node_bench import measure
    folder = Path(out) if out else Path(tempfile.mkdtemp(prefix='organ_scale_'))
    folder.mkdir(parents=True, exist_ok=True)
    rows = []
    for size in sizes:
        mesh = organ_mesh(int(size), echo=echo)
        for model in models:
            scene = _variant_scene(mesh, MODELS[model], sets, folder, f'{model}-{int(size)}')
            result = measure(duration_s=duration_s, scene_file=str(scene), threads=threads)
            from tissue_sim_ros.engine.mesh.files import load_mesh
            row = dict(model=model, asked=int(size), tetrahedra=int(load_mesh(mesh).n_elements), sets=list(sets),
                       wrench_rate_hz=result['wrench_rate_hz'], missed_ticks=result['missed_ticks'],
                       ticks=result['ticks'], ladder_level=result['ladder_level'],
                       ladder_changes=result['ladder_changes'], dropped_time_s=result['dropped_time_s'],
                       node_cpu_pct=result['node_cpu_pct_of_one_core'], budget_use=result['budget_use'],
                       latency_ms_p99=result['latency_ms_p99'], machine_before=result['machine_before'])
            row['holds_50_hz'] = holds(result)
            rows.append(row)
            echo(f"{model:10s} {row['tetrahedra']:7d} tets: {row['wrench_rate_hz']:.2f} Hz, missed "
                 f"{row['missed_ticks']}/{row['ticks']}, ladder {row['ladder_level']} ({row['ladder_changes']} "
                 f"changes), dropped {row['dropped_time_s']:.3g} s, CPU {row['node_cpu_pct']:.0f} %, budget use "
                 f"{row['budget_use']:.2f}: {'holds' if row['holds_50_hz'] else 'does not hold'} 50 Hz")
    for model in models:
        held = [r['tetrahedra'] for r in rows if r['model'] == model and r['holds_50_hz']]
        echo(f'{model}: largest organ mesh holding 50 Hz: {max(held) if held else "none of those tried"}')
    (folder / 'organ_scale.json').write_text(json.dumps(rows, indent=1) + '\n')
    echo(f'wrote {folder / "organ_scale.json"}')
    return rows


def main(sizes, models, sets, duration_s, out, threads):
    run(sizes, models, sets, duration_s, out, threads)
