"""Axial force against needle travel of a run: the plot ``tissue-sim insert`` (a run without ROS)
and ``tissue-sim demo`` (the node's MCAP log) draw. A comparison with measured data goes through
``tissue-sim compare``'s machinery (:func:`tissue_sim_ros.analysis.compare.compare.compare_with_reference`)."""
from __future__ import annotations

import numpy as np

__all__ = ['plot_force_against_travel']


def plot_force_against_travel(path, travel, axial, retracting, *, title: str,
                              labels=('simulated, insertion', 'simulated, retraction'),
                              marks_m=()) -> None:
    """Write a PNG of ``axial`` [N] against ``travel`` [m] (plotted in mm), the insertion and the
    retraction (``retracting``, a bool per sample) as two curves with ``labels``, and a dashed
    line at each travel in ``marks_m`` (puncture events)."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    travel, axial = np.asarray(travel), np.asarray(axial)
    inserting = ~np.asarray(retracting, dtype=bool)
    fig, ax = plt.subplots(figsize=(7, 4.2))
    ax.plot(travel[inserting] * 1e3, axial[inserting], '-', color='C0', label=labels[0])
    ax.plot(travel[~inserting] * 1e3, axial[~inserting], '-', color='C3', label=labels[1])
    for mark in marks_m:
        ax.axvline(mark * 1e3, color='C2', lw=0.8, ls='--')
    ax.set_xlabel('needle travel from start [mm]')
    ax.set_ylabel('axial force on the needle [N]')
    ax.set_title(title)
    ax.grid(alpha=0.3)
    ax.legend(loc='upper left', fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
