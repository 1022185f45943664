"""Headless plate compression of a liver-like block: the reaction force against plate travel.

A block sits on a frictionless floor (z fixed at the bottom, two nodes pinned against rigid
motion) and a frictionless plate moves down at constant speed (z prescribed at the top). The
reaction is the force the tissue exerts on the plate; for small strain it approaches E A strain.
"""
from dataclasses import dataclass

import numpy as np

from tissue_sim_ros.engine.mesh.generators import box_mesh
from tissue_sim_ros.engine.model.material import Material
from tissue_sim_ros.engine.model.tensor_mass import TensorMassModel
from tissue_sim_ros.engine.scene.build import build_material, build_model, build_simulation
from tissue_sim_ros.engine.solver.explicit import Simulation


@dataclass
class CompressionResult:
    time: np.ndarray            # (k,) s
    plate_travel: np.ndarray    # (k,) m, positive downwards
    reaction: np.ndarray        # (k,) N, force of the tissue on the plate along +z (last: settled)
    expected_slope: float       # E A / height [N/m], the small-strain analytic stiffness
    n_elements: int
    time_step: float
    wall_time: float


def plate_compression(size=(0.05, 0.05, 0.03), divisions=(10, 10, 6), material=None,
                      final_strain=0.10, speed=0.01, damping=50.0, samples=60, hold=0.15):
    """Compress the block to ``final_strain`` at ``speed`` [m/s], then hold the plate for ``hold`` [s]
    so the reaction settles; sample the reaction about ``samples`` times during the travel."""
    import time as clock
    material = material or Material(young_modulus=5e3, poisson_ratio=0.45, density=1060.0)
    mesh = box_mesh(size=size, divisions=divisions)
    x = mesh.rest_positions
    bottom = np.flatnonzero(np.isclose(x[:, 2], 0.0))
    top = np.flatnonzero(np.isclose(x[:, 2], size[2]))
    origin = np.flatnonzero(np.all(np.isclose(x, 0.0), axis=1))
    corner = np.flatnonzero(np.all(np.isclose(x, [size[0], 0.0, 0.0]), axis=1))
    sim = Simulation(TensorMassModel(mesh, material), damping=damping)
    sim.fix(bottom, axes='z')
    sim.fix(origin, axes='xy')
    sim.fix(corner, axes='y')
    plate = np.zeros(3)

    def plate_position(t):
        plate[2] = -min(speed * t, final_strain * size[2])
        return plate

    sim.prescribe(top, plate_position, axes='z')
    travel_time = final_strain * size[2] / speed
    duration = travel_time + hold
    steps_per_sample = max(1, int(round(travel_time / samples / sim.dt)))
    times, travel, reaction = [0.0], [0.0], [0.0]
    start = clock.perf_counter()
    while sim.time < duration:
        sim.step(steps_per_sample)
        times.append(sim.time)
        travel.append(-plate_position(sim.time)[2])
        reaction.append(sim.reaction_force(top)[2])
    wall = clock.perf_counter() - start
    return CompressionResult(np.array(times), np.array(travel), np.array(reaction),
                             material.young_modulus * size[0] * size[1] / size[2],
                             mesh.n_elements, sim.dt, wall)


@dataclass
class SceneBlock:
    simulation: object          # engine.solver.explicit.Simulation
    plate_nodes: np.ndarray     # the top face's nodes (z prescribed)
    steps: int                  # steps of the travel and the hold
    expected_reaction: float    # E A strain [N] (A the top's area), the small-strain plate force at the end


def scene_block(scene, strain, *, size=0.02, divisions=6, speed=0.01, hold_s=0.3, mesh_filter=None,
                dt=None, integrator=None) -> SceneBlock:
    """A cube of side ``size`` [m] of the scene's first material and model (every model key, built
    as the scene builds its own), its solver's damping, mass scaling, step rule and integrator, on a
    frictionless floor (two nodes pinned against rigid motion), a frictionless plate pressing its
    top to ``strain`` at ``speed`` [m/s], then held for ``hold_s`` (the mass-proportional damping's
    1 / e time at 50/s is 0.04 s). ``mesh_filter`` changes the box mesh before use (stability's
    slivers); ``dt`` (None: the cube's own critical step times the scene's safety) and
    ``integrator`` override the scene's step rule and integrator."""
    import math

    mesh = box_mesh(size=(size, size, size), divisions=(divisions, divisions, divisions))
    if mesh_filter is not None:
        mesh = mesh_filter(mesh)
    material = build_material(scene.spec['regions'][0])
    model = build_model(mesh, material, scene.spec['model'])
    sim = build_simulation(model, scene.spec['solver'], dt=dt, integrator=integrator)
    x = mesh.rest_positions
    top = np.flatnonzero(np.isclose(x[:, 2], size))
    sim.fix(np.flatnonzero(np.isclose(x[:, 2], 0.0)), axes='z')
    sim.fix(np.flatnonzero(np.all(np.isclose(x, 0.0), axis=1)), axes='xy')
    sim.fix(np.flatnonzero(np.all(np.isclose(x, [size, 0.0, 0.0]), axis=1)), axes='y')
    plate = np.zeros(3)

    def plate_at(t):
        plate[2] = -min(speed * t, strain * size)
        return plate

    sim.prescribe(top, plate_at, axes='z')
    return SceneBlock(sim, top, int(math.ceil((strain * size / speed + hold_s) / sim.dt)),
                      material.young_modulus * size * size * strain)


def plot_compression(result, path):
    """Force against plate travel, with the small-strain line E A / h."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(6, 4))
    ax.plot(result.plate_travel * 1e3, result.reaction, label='simulated reaction')
    ax.plot(result.plate_travel * 1e3, result.expected_slope * result.plate_travel, '--',
            label='E A strain (small strain)')
    ax.set_xlabel('plate travel [mm]')
    ax.set_ylabel('force of tissue on plate [N]')
    ax.set_title(f'plate compression, {result.n_elements} tetrahedra')
    ax.legend()
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
