"""``tissue-sim bench organ``: the node at organ scale, per model and mesh size.

The organ example (config/organ_example.yaml: the project's organ with a tumour and a vessel, on
springs and a ligament, under gravity, the needle at 25 degrees) is meshed at each asked size
(fTetWild has no element-count target: the ideal edge length comes from the volume, and one
correction by the cube root of the count's ratio lands within about 10 %; meshes cached per size in
the user cache; the envelope kept tight for the tumour sets the element size along every surface, so
that an organ asked below about 30000 elements comes out at 28000 to 43000 with it: a smaller organ
is meshed with a looser one, and each row gives the envelope and the inclusions' volume errors), and
each model runs in the node for ``duration_s`` under node-bench (the scripted insertion along the
scene's axis, 15 mm into the tissue and back, at 5 mm/s; the needle inside for most of the window).
A configuration holds 50 Hz when no tick was missed, no simulated time was dropped in the window
(node-bench starts it after the node's start, its prediction workers' and its ladder probe's) and
the budget use ends within 1, with the node's degradation ladder off (``ladder``: on, and then not
stepping down): the engine kept real time with the scene's own settings. The largest mesh that holds
per model is the figure; the scene values of each run (--set) say what it took (the mass scaling,
the threshold, float32).
"""
from __future__ import annotations

import json
import tempfile
from pathlib import Path

import numpy as np

__all__ = ['MODELS', 'ENVELOPE_BOUND', 'LOOSER_ENVELOPES', 'organ_mesh', 'insertion_force',
           'force_nrmse', 'holds', 'run', 'main']

#: model name -> scene values (the four of the seed paper; the full model with the example's
#: exponential law, viscosity and threshold)
MODELS = {
    'linear': {'model.geometric': False, 'model.physical.law': 'none', 'model.viscosity_mu_pa_s': 0.0},
    'physical': {'model.geometric': False, 'model.viscosity_mu_pa_s': 0.0},
    'geometric': {'model.geometric': True, 'model.physical.law': 'none', 'model.viscosity_mu_pa_s': 0.0},
    'full': {},
}
EXAMPLE = 'config/organ_example.yaml'
#: a mesh over this many times the asked count is bound by the mesher's envelope, not its cell
ENVELOPE_BOUND = 1.5
#: the envelopes (relative to the organ's bounding-box diagonal) tried in turn for a smaller organ:
#: fTetWild's own default, then three times it (the inclusions' volumes then move by a few %:
#: each row gives them)
LOOSER_ENVELOPES = (1e-3, 3e-3)


def _cached_count(path: Path) -> int | None:
    """The element count of a cached mesh (from its quality report), None when not cached."""
    try:
        return int(json.loads(path.with_suffix('.quality.json').read_text())['tetrahedra'])
    except (OSError, ValueError, KeyError, TypeError):
        return None if not path.is_file() else _count_of(path)


def _count_of(path: Path) -> int:
    from tissue_sim_ros.engine.mesh.files import load_mesh
    return int(load_mesh(path).n_elements)


def organ_mesh(tetrahedra: int, threads: int = 0, echo=print) -> Path:
    """The organ example meshed at about ``tetrahedra`` elements (module docstring), cached: with
    the mesher's envelope for the inclusions first (``meshing.volume.default_envelope``); where
    that envelope alone keeps the count above ``ENVELOPE_BOUND`` times the asked one (it sets the
    element size along every surface), with each of ``LOOSER_ENVELOPES`` in turn, the last with
    up to two corrections of the cell."""
    from tissue_sim_ros.meshing.organ import write_example_surfaces
    from tissue_sim_ros.meshing.surface import read_surface
    from tissue_sim_ros.meshing.volume import cell_for_count, mesh_surface
    from tissue_sim_ros.system.user_cache import user_cache_dir
    folder = Path(user_cache_dir('organ_meshes') or tempfile.gettempdir()) / 'organ_scale'
    asked = int(tetrahedra)
    surfaces = None
    envelopes = (None,) + LOOSER_ENVELOPES
    for epsilon in envelopes:
        last = epsilon == envelopes[-1]
        name = f'organ-{asked}' if epsilon is None else f'organ-{asked}-envelope-{epsilon:g}'
        path = folder / f'{name}.vtu'
        count = _cached_count(path)
        if count is None:
            if surfaces is None:
                surfaces = write_example_surfaces(folder / 'surfaces')
            inclusions = [('tumour', surfaces['tumour']), ('vessel', surfaces['vessel'])]
            cell = cell_for_count(read_surface(surfaces['organ'], 'mm').volume, asked)
            for attempt in range(3 if last else 2):
                report = mesh_surface(surfaces['organ'], path, units='mm', cell_m=cell, inclusions=inclusions,
                                      epsilon=epsilon, threads=threads, echo=lambda *a: None)
                count = int(report['tetrahedra'])
                echo(f'organ mesh at {cell * 1e3:.2f} mm, envelope {report["options"]["epsilon"]:.3g}: '
                     f'{count} tetrahedra (asked {asked}), mesher {report["seconds"]["mesher"]:.1f} s')
                if abs(count / asked - 1.0) < 0.15 or (count > ENVELOPE_BOUND * asked and not last):
                    break
                cell *= float(np.cbrt(count / asked))
        if count <= ENVELOPE_BOUND * asked:
            break
    return path


def _mesh_facts(mesh: Path) -> dict:
    """The mesher's envelope and the inclusions' volume errors of a cached organ mesh."""
    try:
        report = json.loads(mesh.with_suffix('.quality.json').read_text())
    except (OSError, ValueError):
        return {}
    return {'envelope': report.get('options', {}).get('epsilon'), 'volume_error': report.get('volume_error')}


def _variant_scene(mesh: Path, values: dict, sets, folder: Path, name: str) -> Path:
    from tissue_sim_ros.engine.scene.scene import read_scene_keys, scene_yaml
    from tissue_sim_ros.system.paths import shared_file
    example = shared_file(EXAMPLE)
    spec, _, base = read_scene_keys(example, list(sets), {**values, 'mesh.file': str(mesh.resolve())})
    path = folder / f'{name}.yaml'
    path.write_text(scene_yaml(spec, base, header=[f'{EXAMPLE} at {mesh.name}, {name}']))
    return path


def insertion_force(scene_file, speed_mm_s: float = 5.0, depth_mm: float = 15.0,
                    rate_hz: float = 50.0) -> tuple[np.ndarray, float | None]:
    """(axial force [N] at ``rate_hz``, the run's estimated inertia error) of node-bench's scripted
    insertion (from the scene's start 15 mm into the tissue at 5 mm/s, held 0.5 s, and back) run
    offline on ``scene_file``: what a row's scene values cost in accuracy against the scene as
    configured (``accuracy`` in :func:`run`)."""
    from tissue_sim_ros.engine.driver import SimulationDriver
    from tissue_sim_ros.engine.scene.scene import Scene
    from tissue_sim_ros.ros.clients.drive import insertion_trajectory, scene_start
    start = scene_start(str(scene_file))
    times, positions = insertion_trajectory(start, speed_mm_s * 1e-3, depth_mm * 1e-3, 0.5, rate_hz)
    driver = SimulationDriver(Scene.from_file(str(scene_file)))
    samples = driver.follow(times, positions)
    return -(samples.force @ start.axis), driver.inertia.error


def force_nrmse(force: np.ndarray, reference: np.ndarray) -> float:
    """RMS of the difference over the reference's range (the NRMSE compare and chart report)."""
    return float(np.sqrt(np.mean((force - reference) ** 2)) / max(float(np.ptp(reference)), 1e-300))


def holds(result: dict) -> bool:
    """Whether a node-bench run kept 50 Hz on the scene's own settings (module docstring): no
    missed tick, no dropped time, a budget use within 1 at the end, and the ladder (when on) at
    level 0 throughout."""
    return (result['missed_ticks'] == 0 and result['ladder_level'] <= 0 and result['ladder_changes'] <= 0
            and result['dropped_time_s'] == 0.0 and result['budget_use'] <= 1.0)


def _accuracy(scene: Path, mesh: Path, model: str, sets, folder: Path, size: int, echo) -> dict:
    """The row's scene on the insertion offline: its estimated inertia error and, with ``sets``,
    its axial force's NRMSE against the same model and mesh as configured."""
    force, inertia = insertion_force(scene)
    figures = {'inertia_error': inertia, 'force_nrmse': 0.0}
    if sets:
        reference = _variant_scene(mesh, MODELS[model], (), folder, f'{model}-{size}-as-configured')
        figures['force_nrmse'] = force_nrmse(force, insertion_force(reference)[0])
    echo(f"{model:10s} offline: force NRMSE {figures['force_nrmse']:.4f} against the scene as configured, "
         f"estimated inertia error {inertia if inertia is None else round(inertia, 4)}")
    return figures


def run(sizes=(25_000, 50_000, 100_000), models=tuple(MODELS), sets=(), duration_s=20.0, out=None,
        threads=None, echo=print, accuracy=False, ladder=False) -> list[dict]:
    """Every model on every size under node-bench; rows of figures (printed as they come). With
    ``accuracy``, each row also gets what its scene values cost (:func:`_accuracy`). The node's
    degradation ladder is off unless ``ladder``: the question is whether the scene's own settings
    keep real time, and a ladder that stepped down while the node started (its prediction workers
    load a core for seconds) and did not come back within the window would answer another."""
    from tissue_sim_ros.bench.node_bench import measure
    folder = Path(out) if out else Path(tempfile.mkdtemp(prefix='organ_scale_'))
    folder.mkdir(parents=True, exist_ok=True)
    rows = []
    for size in sizes:
        mesh = organ_mesh(int(size), echo=echo)
        for model in models:
            scene = _variant_scene(mesh, MODELS[model], sets, folder, f'{model}-{int(size)}')
            result = measure(duration_s=duration_s, scene_file=str(scene), threads=threads,
                             params=() if ladder else ('engine.ladder:=false',))
            row = dict(model=model, asked=int(size), tetrahedra=_count_of(mesh), **_mesh_facts(mesh),
                       sets=list(sets),
                       wrench_rate_hz=result['wrench_rate_hz'], missed_ticks=result['missed_ticks'],
                       ticks=result['ticks'], ladder_level=result['ladder_level'],
                       ladder_changes=result['ladder_changes'], dropped_time_s=result['dropped_time_s'],
                       node_cpu_pct=result['node_cpu_pct_of_one_core'], budget_use=result['budget_use'],
                       latency_ms_p99=result['latency_ms_p99'], machine_before=result['machine_before'])
            row['holds_50_hz'] = holds(result)
            if accuracy:
                row.update(_accuracy(scene, mesh, model, sets, folder, int(size), echo))
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


def main(sizes, models, sets, duration_s, out, threads, accuracy=False, ladder=False):
    run(sizes, models, sets, duration_s, out, threads, accuracy=accuracy, ladder=ladder)
