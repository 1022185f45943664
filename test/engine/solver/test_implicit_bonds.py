"""The needle's bonds held inside the implicit steps (engine/solver/implicit_bonds.py): the same as
prescribed displacements, and a barycentric bond held exactly and in balance."""

import numpy as np
import pytest

import tissue_sim_ros as ts
from support.meshes import _bottom, _top
from tissue_sim_ros.engine.solver.implicit_bonds import BondRows


class _Bonds:
    """A coupling that bonds sample points ((s, J) weights over (s, J) nodes) to fixed targets."""

    def __init__(self, nodes, weights, targets):
        self.rows = BondRows.along_axes(nodes, weights, targets)

    def implicit_bonds(self):
        return (self.rows,)

    @property
    def forces(self):
        return self.rows.forces.reshape(-1, 3)


@pytest.mark.parametrize('integrator', ['quasi_static', 'implicit'])
def test_bonds_held_in_the_solve_are_prescribed_displacements(cube, liver, integrator):
    """Bonding four top nodes to targets 1 mm down and sideways (engine/solver/implicit_bonds.py) gives
    the same step as prescribing those nodes' displacements: the same field (1e-9 relative) and
    the bonds' forces equal to the force that holds the prescribed nodes (its reaction: the
    internal force it balances, quasi-static, or the full unbalance, backward Euler)."""
    top = _top(cube)
    centre = cube.rest_positions[top, :2].mean(axis=0)
    held = top[np.argsort(np.linalg.norm(cube.rest_positions[top, :2] - centre, axis=1))[:4]]
    move = np.array([2e-4, -1e-4, -1e-3])
    dt = 0.01

    def simulation():
        return ts.Simulation(ts.TensorMassModel(cube, liver), damping=50.0, fixed=_bottom(cube), dt=dt,
                             integrator=integrator, newton_tolerance=1e-11)

    bonded = simulation()
    bonds = _Bonds(held[:, None], np.ones((4, 1)), cube.rest_positions[held] + move)
    bonded.couplings.append(bonds)
    prescribed = simulation()
    prescribed.prescribe(held, lambda t: move)
    for _ in range(3):
        bonded.step()
        prescribed.step()
    scale = np.abs(prescribed.displacement).max()
    assert np.abs(bonded.displacement - prescribed.displacement).max() < 1e-9 * scale
    np.testing.assert_allclose(bonded.displacement[held], np.tile(move, (4, 1)), rtol=0, atol=1e-12 * scale)
    # what holds the prescribed nodes: the unbalance m (v - v_n) / dt + gamma v - f there
    before = simulation()
    before.prescribe(held, lambda t: move)
    before.step(2)
    v_old = before.velocity[held].copy()
    holding = (prescribed.mass[held, None] * ((prescribed.velocity[held] - v_old) / dt
                                              + 50.0 * prescribed.velocity[held])
               if integrator == 'implicit' else 0.0) - prescribed.internal_force[held]
    forces = bonds.forces
    assert np.abs(forces).max() > 1e-3
    np.testing.assert_allclose(forces, holding, rtol=0, atol=1e-7 * np.abs(forces).max())


def test_barycentric_bond_held_exactly_and_in_balance(cube, liver):
    """A sample inside a top face, bonded 1 mm down: after quasi-static steps its material point
    sits on the target (1e-12 m), and the bond's force balances the tissue's (the internal forces
    of the free nodes sum to minus it: no other force acts on them)."""
    top = _top(cube)
    nodes = top[np.argsort(np.linalg.norm(cube.rest_positions[top, :2] - 0.01, axis=1))[:3]]
    weights = np.array([[0.5, 0.3, 0.2]])
    target = weights @ cube.rest_positions[nodes] + [0.0, 0.0, -1e-3]
    sim = ts.Simulation(ts.TensorMassModel(cube, liver), fixed=_bottom(cube), dt=0.05,
                        integrator='quasi_static', newton_tolerance=1e-11)
    bonds = _Bonds(nodes[None, :], weights, target)
    sim.couplings.append(bonds)
    sim.step(2)
    point = weights @ (cube.rest_positions[nodes] + sim.displacement[nodes])
    assert np.abs(point - target).max() < 1e-12
    force = bonds.forces[0]
    assert force[2] < -1e-3                               # it pushes the tissue down
    free = sim.dof_kind == 0
    balance = np.where(free, sim.internal_force, 0.0).sum(axis=0) + force
    assert np.abs(balance).max() < 1e-6 * np.abs(force).max()
