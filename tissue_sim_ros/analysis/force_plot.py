"""Axial force against needle travel over the bovine-liver measurement: the one plot that
``tissue-sim insert`` (a run without ROS) and ``tissue-sim demo`` (the node's MCAP log) draw."""
from __future__ import annotations

import numpy as np

from tissue_sim_ros.analysis.insertion import DATA_DIR, okamura_main_trace

__all__ = ['plot_force_against_travel']

REFERENCE_LABEL = 'bovine liver, ex vivo (Okamura et al. 2004, 3 mm/s)'


def plot_force_against_travel(path, travel, axial, retracting, *, title: str,
                              labels=('simulated, insertion', 'simulated, retraction'),
                              reference: bool = True, marks_m=()) -> None:
    """Write a PNG of ``axial`` [N] against ``travel`` [m] (plotted in mm), the insertion and the
    retraction (``retracting``, a bool per sample) as two curves with ``labels``, the measured
    trace behind them when ``reference`` and the data are there, and a dashed line at each
    travel in ``marks_m`` (puncture events)."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    travel, axial = np.asarray(travel), np.asarray(axial)
    inserting = ~np.asarray(retracting, dtype=bool)
    fig, ax = plt.subplots(figsize=(7, 4.2))
    if reference and DATA_DIR.exists():
        depth, force = okamura_main_trace()
        ax.plot(depth * 1e3, force, '.', ms=3, color='0.55', label=REFERENCE_LABEL)
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
