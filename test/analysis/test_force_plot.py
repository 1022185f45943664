"""The one force-against-travel plot (insert and demo): what it draws is the data it was given,
split into insertion and retraction; and the comparison with the bovine liver through compare's
machinery."""

import numpy as np
import pytest

matplotlib = pytest.importorskip('matplotlib')

from tissue_sim_ros.analysis.force_plot import plot_force_against_travel  # noqa: E402


@pytest.fixture
def drawn(monkeypatch):
    """The lines of each figure saved, as {label: (x, y)}, and the vertical marks' x."""
    from matplotlib.figure import Figure
    figures = []
    real_savefig = Figure.savefig

    def savefig(fig, path, **kwargs):
        ax = fig.axes[0]
        lines = {line.get_label(): (np.asarray(line.get_xdata()), np.asarray(line.get_ydata()))
                 for line in ax.get_lines()}
        figures.append((lines, ax.get_title()))
        real_savefig(fig, path, **kwargs)
    monkeypatch.setattr(Figure, 'savefig', savefig)
    return figures


def test_the_plot_draws_insertion_retraction_marks_and_the_measurement(tmp_path, drawn):
    travel = np.array([0.0, 0.005, 0.010, 0.005, 0.0])
    axial = np.array([0.0, 0.4, 1.1, -0.2, 0.0])
    retracting = np.array([False, False, False, True, True])
    plot_force_against_travel(tmp_path / 'f.png', travel, axial, retracting, title='run',
                              labels=('in', 'out'), marks_m=[0.007])
    (lines, title), = drawn
    assert title == 'run' and (tmp_path / 'f.png').stat().st_size > 0
    np.testing.assert_allclose(lines['in'][0], [0.0, 5.0, 10.0])       # mm
    np.testing.assert_allclose(lines['in'][1], [0.0, 0.4, 1.1])
    np.testing.assert_allclose(lines['out'][0], [5.0, 0.0])
    np.testing.assert_allclose(lines['out'][1], [-0.2, 0.0])
    marks = [x for label, (x, _) in lines.items() if label.startswith('_')]
    assert len(marks) == 1 and np.allclose(marks[0], 7.0)
    assert sorted(k for k in lines if not k.startswith('_')) == ['in', 'out']


def test_the_bovine_liver_compared_with_itself_has_no_error_and_the_same_punctures(tmp_path, drawn):
    """compare_with_reference, given the reference's own trace as the 'simulation' (time, travel
    with another origin, force): NRMSE 0 over the insertion, every puncture at the same depth, and
    the plot draws the data and the curve on one depth axis."""
    from tissue_sim_ros.analysis.compare.compare import compare_with_reference
    from tissue_sim_ros.analysis.compare.reference_data import SPEED_M_S, bovine_liver_trace
    depth, force = bovine_liver_trace()
    comparison = compare_with_reference(depth / SPEED_M_S, depth + 0.004, force,
                                        plot=tmp_path / 'self.png', label='itself')
    assert comparison.errors['nrmse'] == pytest.approx(0.0, abs=1e-6)   # travel rounding at the drops
    assert comparison.errors['count'] > 50
    assert [p.travel_m for p in comparison.simulated_punctures] == pytest.approx(
        [p.travel_m for p in comparison.measured_punctures], abs=1e-9)
    (lines, title), = drawn
    assert 'NRMSE 0.000' in title and 'itself' in lines
