"""Benchmarks: each prints its figures (and writes them into ``--out DIR``); none asserts a time.

docs/performance.md gives how to run each and its latest figures.

- :mod:`.speed`: force evaluation and explicit step per model and mesh size (``tissue-sim bench``);
- :mod:`.cold_start`: a fresh install's first start, compiles included;
- :mod:`.inertia`: the mass scaling's estimated inertia error against the error it adds;
- :mod:`.ripple`: how smooth the axial force is after a puncture;
- :mod:`.study`: replay and compare timings; ``compare`` on a process pool and on a Dask cluster;
- :mod:`.calibration`: ``calibrate`` on synthetic data with known values;
- :mod:`.layered`: ``propose`` and ``calibrate`` on synthetic two- and three-layer phantoms;
- :mod:`.organ_scale`: the node at organ scale, per model and mesh size (``tissue-sim bench organ``);
- :mod:`.steering`: a flexible needle in air and in the tissue, its curvature, its step's cost;
- :mod:`.node_bench`, :mod:`.node_bench_figures`, :mod:`.node_bench_paired`: the node's timing
  from outside, its figures, and paired runs against another revision (``tissue-sim node-bench``);
- :mod:`.background_load`, :mod:`.prediction_burst`: busy processes and a listener beside the
  node; a burst of planner requests during a run;
- :mod:`.robot_graph`: TF input against the pose topic, the action against the topic pair.
"""
__all__ = ['background_load', 'calibration', 'cold_start', 'inertia', 'layered', 'node_bench',
           'node_bench_figures', 'node_bench_paired', 'organ_scale', 'prediction_burst', 'ripple',
           'robot_graph', 'speed',
           'steering', 'study']
