"""The evidence side: runs without ROS, and the simulation held against measurements.

Sub-packages:

- :mod:`~tissue_sim_ros.analysis.compare`: load-cell trials -> measured motion -> simulation ->
  alignment -> errors beside the repeats' own spread (``tissue-sim compare``);
- :mod:`~tissue_sim_ros.analysis.calibration`: scene keys fitted to trials, cross-validated across
  speeds (``tissue-sim calibrate``);
- :mod:`~tissue_sim_ros.analysis.charting`: speed against accuracy, the stability map, the least
  model a scene needs, the mass-scaling rule (``chart``, ``stability``, ``recommend``).

Modules here:

- :mod:`.jobs`: independent simulations over the cores (a process pool or Dask), with progress;
- :mod:`.insertion`, :mod:`.force_plot`: a straight insertion without ROS (``tissue-sim insert``);
- :mod:`.predict`: a candidate path's prediction without ROS (``tissue-sim predict``);
- :mod:`.replay`: a node log through the engine again (``tissue-sim replay``);
- :mod:`.steering`: a flexible needle's path, its bend and curvature (``tissue-sim bench steering``);
- :mod:`.synthetic_study`: a load-cell study made by the simulator, for tests and benchmarks;
- :mod:`.synthetic_curves`: layered force curves from a formula whose every event is known (pre-drops,
  rounded peaks, partial drops), for the detectors' tests;
- :mod:`.demo`: the main job (``tissue-sim demo``).
"""
__all__ = ['calibration', 'charting', 'compare', 'demo', 'force_plot', 'insertion', 'jobs', 'predict',
           'replay', 'steering', 'synthetic_curves', 'synthetic_study']
