"""What calibrate reports (analysis/calibration/report.py): a speed whose calibrated error is above
the nearest other speed's measured curve is named with both figures."""


def test_a_model_farther_from_a_speeds_data_than_another_speeds_data_is_named():
    """Fitted or held out, a speed whose calibrated NRMSE is above the nearest other speed's
    measured curve is named with both figures; one below it, or without a baseline, is not."""
    from tissue_sim_ros.analysis.calibration.report import _warnings
    fit = {'failed': [], 'finish': [], 'inertia': {'error_at_optimum': 0.01, 'bound': 0.02}}
    spread = {'correlated_pairs': [], 'insensitive': []}

    def row(role, speed, model, nearest):
        return {'role': role, 'speed_m_s': speed, 'nrmse_calibrated': model, 'nearest_speed_m_s': 0.002,
                'nearest_speed_nrmse': nearest}
    rows = [row('fit', 0.001, 0.0233, 0.0137), row('fit', 0.003, 0.0100, 0.0108),
            row('held out', 0.004, 0.05, 0.03), row('fit', 0.005, 0.02, None)]
    out = _warnings(fit, rows, spread)
    assert len(out) == 2
    assert out[0].startswith('fitted 1 mm/s') and '0.023' in out[0] and '0.014' in out[0]
    assert out[1].startswith('held-out 4 mm/s') and '0.050' in out[1] and '0.030' in out[1]
