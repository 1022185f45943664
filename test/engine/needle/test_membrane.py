"""The needle against a membrane (engine/needle/membrane.py): force and energy criteria, one
puncture per membrane."""

import math

import numpy as np
import pytest

from support.scenes import axial, push, small_scene


def test_force_criterion_punctures_within_one_step_of_the_threshold():
    threshold = 0.12
    scene = small_scene(region={'membrane': {'criterion': 'force', 'rupture_force_n': threshold}})
    sim, needle = scene.simulation, scene.needle
    p0, q = scene.needle_pose
    history = []
    for k in range(1, 4000):
        needle.set_pose(p0 + np.array([0.0, 0.0, -3e-3 * k * sim.dt]), q)
        sim.step(1)
        needle.after_step(sim.dt)
        history.append(float(np.dot(needle.contact_force, needle.axis)))
        if needle.puncture_events:
            break
    assert needle.puncture_events, 'no puncture'
    assert history[-1] >= threshold > history[-2]
    assert needle.phase == 'inserted'


def test_energy_criterion_rupture_force_falls_with_speed_as_the_work_balance_predicts():
    """Energy criterion (Mahvash and Dupont 2010): rupture when W = integral of F dd since contact
    reaches G A. With F(d, v) = f(d) + v beta(d) (beta the viscous force per unit speed), W = G A
    gives dF_r/dv = beta(d) - F'(d) B(d) / F_r, B = integral of beta: the rupture force falls
    with speed where the curve stiffens faster (n = d F' / F) than the viscous force grows
    (beta(d) / mean beta). A flat punch on a linear material has n ~ 1 and beta rising, so it
    rose (+2 %); here a stiffening law (exponential, 1 (e^(8 s) - 1) on mu, viscosity not scaled
    by it) gives n ~ 1.6 against 1.4 at rupture near 5 mm. Checked against the prediction from
    the 2 mm/s run alone: its curve plus (10 - 2) mm/s times beta, beta = P_v / v^2 from the
    model's viscous forces (the power balance of the viscosity test), integrated to G A.
    No mass-proportional damping, so the speed effect is the tissue's viscosity alone."""
    toughness, area = 440.0, math.pi * 1.2e-3 ** 2
    runs = {}
    for speed in (2e-3, 10e-3):
        scene = small_scene(model={'geometric': True, 'viscosity_mu_pa_s': 200.0,
                                   'physical': {'law': 'exponential', 'mu_amplitude': 1.0, 'mu_rate': 8.0}},
                            solver={'damping_per_s': 0.0},
                            region={'membrane': {'criterion': 'energy', 'toughness_j_per_m2': toughness}})
        sim, model = scene.simulation, scene.model
        rows = []
        for _ in push(scene, 0.008, speed, tick=0.01):
            if scene.puncture_events:
                break
            if scene.phase == 'contact':
                viscous = model.internal_forces(sim.displacement, sim.velocity) - model.internal_forces(sim.displacement)
                power = -float(np.vdot(viscous, sim.velocity))
                rows.append((scene.tip_depth, axial(scene), power / speed ** 2, scene.needle.patch.work))
        assert scene.puncture_events, f'no rupture at {speed} m/s'
        event = scene.puncture_events[0]
        runs[speed] = (event['tip_depth_m'], event['axial_force_n'], np.array(rows).T)
    (d_slow, f_slow, (depth, force, beta, work)), (d_fast, f_fast, _) = runs[2e-3], runs[10e-3]
    dv = 10e-3 - 2e-3
    predicted_work = work + dv * np.concatenate([[0.0], np.cumsum(0.5 * (beta[1:] + beta[:-1]) * np.diff(depth))])
    d_pred = np.interp(toughness * area, predicted_work, depth)
    f_pred = np.interp(d_pred, depth, force + dv * beta)
    print(f'rupture at 2 mm/s {d_slow * 1e3:.3f} mm {f_slow:.4f} N, at 10 mm/s {d_fast * 1e3:.3f} mm {f_fast:.4f} N '
          f'({f_fast - f_slow:+.4f} N); predicted from the 2 mm/s run {d_pred * 1e3:.3f} mm {f_pred:.4f} N '
          f'({f_pred - f_slow:+.4f} N)')
    assert d_fast < d_slow and f_fast < f_slow
    assert d_fast - d_slow == pytest.approx(d_pred - d_slow, rel=0.3)
    assert f_fast - f_slow == pytest.approx(f_pred - f_slow, rel=0.3)


def test_a_membrane_is_punctured_once_and_the_needle_stays_in():
    """10 mm/s on 2 mm cells, a weak capsule (0.1 N) and cutting (0.2 N): one puncture, then
    'inserted' at every tick. The cutting push carried the first shaft point, a surface node,
    0.5 mm ahead of the tip; releasing it as 'passed back over' took the needle out and the
    capsule was punctured again at once (three events, at 0.9, 1.3 and 1.7 mm of travel)."""
    scene = small_scene(region={'membrane': {'criterion': 'force', 'rupture_force_n': 0.1}, 'cutting_force_n': 0.2})
    phases = []
    for _ in push(scene, 0.0045, 10e-3, tick=0.005):
        if scene.puncture_events:
            phases.append(scene.phase)
    assert len(scene.puncture_events) == 1
    assert phases and set(phases) == {'inserted'}
