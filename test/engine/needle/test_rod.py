"""The needle's shaft as a discrete elastic rod (engine/needle/rod.py): clamped in air against the
cantilever's closed form F L^3 / (3 E I) and the large-deflection elastica (scipy's solve_bvp,
independent of the rod), its forces and stiffness against finite differences of its energy, its
transported frames."""
import math

import numpy as np
import pytest

from tissue_sim_ros.bench.steering import elastica_tip
from tissue_sim_ros.engine.needle import rod

AXIS = np.array([0.0, 0.0, 1.0])


def clamped_tip(load_ratio, segments, length=0.08, bending=1.6e-3, axial=2.2e4):
    """(tip x, tip z, tip rotation) of a rod clamped at the origin along +z under a tip load
    F = load_ratio EI / L^2 along +x."""
    nodes = rod.straight_nodes([0.0, 0.0, 0.0], AXIS, length, segments)
    loads = np.zeros_like(nodes)
    loads[-1, 0] = load_ratio * bending / length ** 2
    iterations, residual = rod.static_solve(nodes, length / segments, bending, axial, AXIS, loads, 1,
                                            1e-9 * loads[-1, 0], 200)
    assert residual < 1e-3 * loads[-1, 0]            # (the stretching's round-off, 1e-8 N here)
    last = nodes[-1] - nodes[-2]
    return nodes[-1, 0], nodes[-1, 2], math.atan2(last[0], last[2])


@pytest.mark.parametrize('segments', [20, 40])
def test_a_clamped_rod_under_a_small_tip_load_deflects_f_l3_over_3_ei(segments):
    load_ratio = 1e-3                                      # F L^2 / EI: a tip rotation of 0.03 degrees
    x, _, angle = clamped_tip(load_ratio, segments)
    assert x == pytest.approx(load_ratio * 0.08 / 3.0, rel=0.01)
    assert angle == pytest.approx(load_ratio / 2.0, rel=0.01)     # F L^2 / (2 E I)


@pytest.mark.parametrize('load_ratio', [1.2, 4.0])
def test_the_rod_follows_the_large_deflection_elastica(load_ratio):
    """30.8 and 64.2 degrees of tip rotation: the tip where the elastica puts it within 2 %."""
    ex, ez, e_angle = elastica_tip(load_ratio, 0.08)
    rx, rz, r_angle = clamped_tip(load_ratio, 40)
    assert math.degrees(e_angle) > 30.0
    assert rx == pytest.approx(ex, rel=0.02) and rz == pytest.approx(ez, rel=0.02)
    assert r_angle == pytest.approx(e_angle, rel=0.02)


def test_the_rods_forces_and_stiffness_are_its_energys_derivatives():
    rng = np.random.default_rng(3)
    n, h, bending, axial = 5, 0.01, 0.7, 30.0
    nodes = rod.straight_nodes([0.0, 0.0, 0.0], AXIS, n * h * 1.02, n) + 1e-4 * rng.standard_normal((n + 1, 3))
    base_axis = np.array([0.1, 0.0, 1.0]) / math.hypot(0.1, 1.0)

    def gradient_band(x):
        g, band = np.zeros((n + 1, 3)), np.zeros((3 * (n + 1), rod.BANDS + 1))
        rod.assemble(x, h, bending, axial, base_axis, g, band)
        return g, band

    g, band = gradient_band(nodes)
    eps = 1e-7
    numeric = np.zeros_like(g)
    hessian = np.zeros((3 * (n + 1), 3 * (n + 1)))
    for i in range(3 * (n + 1)):
        step = np.zeros(3 * (n + 1))
        step[i] = eps
        up, down = nodes + step.reshape(-1, 3), nodes - step.reshape(-1, 3)
        numeric.reshape(-1)[i] = (rod.rod_energy(up, h, bending, axial, base_axis)
                                  - rod.rod_energy(down, h, bending, axial, base_axis)) / (2 * eps)
        hessian[:, i] = ((gradient_band(up)[0] - gradient_band(down)[0]) / (2 * eps)).reshape(-1)
    assert np.abs(numeric - g).max() < 1e-6 * np.abs(g).max()
    dense = np.zeros_like(hessian)
    for i in range(len(dense)):
        for d in range(rod.BANDS + 1):
            if i + d < len(dense):
                dense[i, i + d] = dense[i + d, i] = band[i, d]
    # every segment stretched here: the compressive geometric term the solve leaves out is absent
    assert np.abs(hessian - dense).max() < 1e-5 * np.abs(dense).max()
    rhs = rng.standard_normal(len(dense))
    spd = dense + np.eye(len(dense)) * np.abs(dense).max()
    packed = np.array([[spd[i, i + d] if i + d < len(spd) else 0.0 for d in range(rod.BANDS + 1)]
                       for i in range(len(spd))])
    solved = rhs.copy()
    assert rod.band_solve(packed, solved, 1)
    expected = np.zeros_like(rhs)
    expected[3:] = np.linalg.solve(spd[3:, 3:], rhs[3:])
    assert np.allclose(solved, expected, rtol=1e-10, atol=1e-14)


def test_the_transported_frames_do_not_twist_about_the_centreline():
    """A rod bent in the x-z plane keeps the base frame's y (normal to the plane) in every frame,
    and the tip frame's quaternion turns it back into the frame."""
    from tissue_sim_ros.engine.needle.pose import rotation_matrix
    s = np.linspace(0.0, 0.05, 26)
    nodes = np.column_stack([0.02 * (1 - np.cos(s / 0.02)), np.zeros_like(s), 0.02 * np.sin(s / 0.02)])
    frames = np.zeros((25, 3, 3))
    rod.transport_frames(nodes, np.eye(3), frames)
    assert np.allclose(frames[:, :, 1], [0.0, 1.0, 0.0], atol=1e-12)
    assert np.allclose(np.einsum('kij,kil->kjl', frames, frames), np.eye(3), atol=1e-12)
    quaternions = np.zeros((25, 4))
    rod.frame_quaternions(frames, quaternions)
    assert np.allclose([rotation_matrix(q) for q in quaternions], frames, atol=1e-12)


