"""The one force-against-travel plot (insert and demo): what it draws is the data it was given,
split into insertion and retraction, over the measured bovine-liver trace."""
import numpy as np
import pytest

matplotlib = pytest.importorskip('matplotlib')

from tissue_sim_ros.analysis.force_plot import plot_force_against_travel  # noqa: E402
from tissue_sim_ros.analysis.insertion import DATA_DIR, okamura_main_trace  # noqa: E402


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
    if DATA_DIR.exists():
        depth, force = okamura_main_trace()
        (measured,) = [v for k, v in lines.items() if k.startswith('bovine liver')]
        np.testing.assert_allclose(measured[0], depth * 1e3)
        np.testing.assert_allclose(measured[1], force)


def test_without_reference_only_the_run_is_drawn(tmp_path, drawn):
    plot_force_against_travel(tmp_path / 'f.png', [0.0, 0.001], [0.0, 0.1], [False, False],
                              title='t', reference=False)
    (lines, _), = drawn
    assert sorted(lines) == ['simulated, insertion', 'simulated, retraction']
    assert lines['simulated, retraction'][0].size == 0
