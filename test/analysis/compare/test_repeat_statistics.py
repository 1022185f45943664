"""Repeats on a common grid: their mean and spread against the curve they were made from, the
leave-one-out noise floor against its formula, and the nearest-speed baseline worked by hand."""

import numpy as np
import pytest

from tissue_sim_ros.analysis.compare.repeat_statistics import (ForceCurve, common_grid, mean_and_spread,
                                                               nearest_speed_baseline, noise_floor_nrmse)
from tissue_sim_ros.io.trials.trial import Trial

SPEED, DEPTH, HOLD_S, REST_S = 2e-3, 20e-3, 1.0, 0.5


def insertion_force(below_m, retracting):
    """The clean force [N] at depth ``below_m`` below the surface: 0.1 N/mm going in with a
    smooth bend, a 0.5 N pull coming out, none outside the tissue."""
    inward = 100.0 * below_m + 2e4 * below_m ** 2
    return np.where(below_m > 0, np.where(retracting, -0.5, inward), 0.0)


def repeat(rng, *, gap, noise, jitter=True, scale=1.0):
    """One repeat: rest, advance by DEPTH at SPEED, hold, retract; the surface at travel ``gap``.
    Sampled at 88-100 Hz with jitter (or exactly 100 Hz); returns the curve and its contact
    index (the first sample at or past the surface)."""
    t_depth = REST_S + DEPTH / SPEED
    t_out = t_depth + HOLD_S
    duration = t_out + DEPTH / SPEED
    if jitter:
        time = np.concatenate([[0.0], np.cumsum(rng.uniform(0.01, 1 / 88.0, int(duration * 100)))])
        time = time[time <= duration]
    else:
        time = np.arange(0.0, duration, 0.01)
    travel = np.where(time <= t_out, np.clip(SPEED * (time - REST_S), 0, DEPTH),
                      np.clip(DEPTH - SPEED * (time - t_out), 0, DEPTH))
    force = scale * insertion_force(travel - gap, time > t_out)
    contact = int(np.flatnonzero(travel >= gap)[0])
    return ForceCurve(time, force + rng.normal(0, noise, len(time)), travel, contact)


def test_the_mean_of_repeats_is_their_curve_on_both_legs_and_the_spread_their_noise():
    rng = np.random.default_rng(1)
    sigma, n_repeats = 0.02, 12
    curves = [repeat(rng, gap=rng.uniform(3e-3, 6e-3), noise=sigma) for _ in range(n_repeats)]
    aligned = common_grid(curves, step=2e-4)
    grid, mean, std, count = mean_and_spread(curves, step=2e-4)
    np.testing.assert_array_equal(grid, aligned.grid)
    insertion, retraction = aligned.leg == 'insertion', aligned.leg == 'retraction'
    assert insertion.sum() > 50 and retraction.sum() > 50
    assert grid[insertion][0] == 0.0 and np.all(np.diff(grid[insertion]) > 0)
    assert np.all(np.diff(grid[retraction]) < 0)
    # the insertion leg ends where the deepest-touching repeat ends, DEPTH minus its gap, less
    # up to a grid step, the 10 um depth tolerance and one sample's travel
    shortest = DEPTH - max(curve.travel_m[curve.contact_index] for curve in curves)
    assert shortest - 2e-4 - 1e-5 - SPEED / 88.0 <= grid[insertion][-1] <= shortest
    truth = insertion_force(grid, retraction)
    # the contact sample lies up to one sample (2 mm/s / 88 Hz) past the surface: the steepest
    # slope (0.1 N/mm + 2 * 2e4 N/m^2 * 20 mm = 0.9 N/mm) times that, plus 4 standard errors
    misplacement = 0.9e3 * SPEED / 88.0
    inner = (grid > 0.5e-3) & (np.abs(grid - grid[insertion][-1]) > 0.5e-3)   # off the edges
    assert np.all(np.abs(mean - truth)[inner] < misplacement + 4 * sigma / np.sqrt(n_repeats))
    assert np.all(count == n_repeats)
    # on the retraction leg the force is a constant pull: the spread there is the noise, as
    # linear resampling leaves it: a grid point a fraction a of the way between two samples
    # weighs their independent noise by 1 - a and a, a variance sigma^2 ((1 - a)^2 + a^2), on
    # average 2 sigma^2 / 3 with a uniform on [0, 1] (jittered samples, a grid that misses them)
    assert np.mean(std[retraction & inner]) == pytest.approx(sigma * np.sqrt(2 / 3), rel=0.08)


def test_the_time_grid_runs_from_contact_over_the_shortest_repeat():
    rng = np.random.default_rng(2)
    curves = [repeat(rng, gap=gap, noise=0.01) for gap in (3e-3, 5e-3)]
    grid, mean, std, count = mean_and_spread(curves, by='time_since_contact', step=0.05)
    shortest = min(curve.time_s[-1] - curve.time_s[curve.contact_index] for curve in curves)
    assert grid[0] == 0.0 and grid[-1] == pytest.approx(shortest, abs=0.05)
    np.testing.assert_allclose(np.diff(grid), 0.05)
    assert common_grid(curves, by='time_since_contact').leg is None
    assert np.all(count == 2) and np.isfinite(std).all()


def test_the_noise_floor_of_noisy_copies_of_one_curve_follows_from_the_noise():
    # Each repeat is c + e_i, e_i independent with standard deviation sigma. Against the mean of
    # the n - 1 others, c + sum_{j != i} e_j / (n - 1), the error e_i - sum_{j != i} e_j / (n - 1)
    # has variance sigma^2 + sigma^2 / (n - 1): an RMSE of sigma * sqrt(1 + 1 / (n - 1)),
    # normalised by the repeat's own range on the compared samples.
    rng = np.random.default_rng(3)
    sigma, n_repeats = 0.05, 6
    curves = [repeat(rng, gap=4e-3, noise=sigma, jitter=False) for _ in range(n_repeats)]
    contact = curves[0].contact_index
    assert all(curve.contact_index == contact for curve in curves)
    # on a grid at the samples (100 Hz from the contact) the resampling leaves the noise alone
    floor = noise_floor_nrmse(curves, by='time_since_contact', step=0.01)
    ranges = [np.ptp(curve.force_n[contact:]) for curve in curves]
    expected = np.mean([sigma * np.sqrt(1 + 1 / (n_repeats - 1)) / r for r in ranges])
    assert floor == pytest.approx(expected, rel=0.05)


def test_the_noise_floor_needs_two_repeats_and_grows_with_the_noise():
    rng = np.random.default_rng(4)
    assert np.isnan(noise_floor_nrmse([repeat(rng, gap=4e-3, noise=0.05)]))
    quiet = [repeat(rng, gap=4e-3, noise=0.01, jitter=False) for _ in range(4)]
    loud = [repeat(rng, gap=4e-3, noise=0.04, jitter=False) for _ in range(4)]
    assert noise_floor_nrmse(loud) > 3 * noise_floor_nrmse(quiet)


def test_the_nearest_speed_baseline_by_hand():
    # speed v scales the clean curve by 1 + 100 v (v in m/s): the nearest speed's mean differs
    # from this one's by 100 (u - v) x the curve, an RMSE of 100 |u - v| x rms(curve) on the
    # grid, normalised by this speed's range (1 + 100 v) x range(curve). Sampled at 100 Hz with
    # the surface on a sample, so that every repeat touches at the same travel.
    rng = np.random.default_rng(5)
    speeds = (1e-3, 2e-3, 3.5e-3)
    by_speed = {speed: [repeat(rng, gap=4e-3, noise=0.0, jitter=False, scale=1 + 100 * speed)
                        for _ in range(3)] for speed in speeds}
    baseline = nearest_speed_baseline(by_speed, step=1e-4)
    assert [baseline[speed]['nearest_speed_m_s'] for speed in speeds] == [2e-3, 1e-3, 2e-3]
    aligned = common_grid(by_speed[1e-3] + by_speed[2e-3], step=1e-4)
    clean = insertion_force(aligned.grid, aligned.leg == 'retraction')
    for speed in speeds:
        nearest = baseline[speed]['nearest_speed_m_s']
        rmse = 100 * abs(nearest - speed) * np.sqrt(np.mean(clean ** 2))
        normaliser = (1 + 100 * speed) * np.ptp(clean)
        assert baseline[speed]['rmse_n'] == pytest.approx(rmse, rel=0.01)
        assert baseline[speed]['nrmse'] == pytest.approx(rmse / normaliser, rel=0.01)
    with pytest.raises(ValueError, match='1 speed'):
        nearest_speed_baseline({1e-3: by_speed[1e-3]})


def test_bad_input_is_named():
    rng = np.random.default_rng(6)
    good = repeat(rng, gap=4e-3, noise=0.01)
    with pytest.raises(ValueError, match="by = 'depth'"):
        common_grid([good], by='depth')
    with pytest.raises(ValueError, match=r'curves\[1\] has no travel_m'):
        common_grid([good, ForceCurve(good.time_s, good.force_n)])
    with pytest.raises(ValueError, match=r'curves\[0\]: no contact found'):
        common_grid([ForceCurve(good.time_s, np.zeros_like(good.time_s), good.travel_m)])
    with pytest.raises(ValueError, match='force_n has 2 samples'):
        ForceCurve(good.time_s, [0.0, 1.0])


def test_a_trial_gives_its_axial_force_not_its_three_force_columns():
    time = np.linspace(0.0, 1.0, 5)
    three_columns = np.arange(15.0).reshape(5, 3)
    trial = Trial('t.csv', time, axial_force_n=-time, travel_m=2 * time, force_n=three_columns)
    curve = ForceCurve.from_trial(trial, contact_index=2)
    np.testing.assert_array_equal(curve.force_n, -time)
    np.testing.assert_array_equal(curve.travel_m, 2 * time)
    assert curve.contact_index == 2
