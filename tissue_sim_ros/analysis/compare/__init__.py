"""``tissue-sim compare`` and ``tissue-sim inspect``: the simulation on the measured motion of
load-cell trials, and what a data description reads.

- :mod:`.alignment`: two force records on one time base (resampling, cross-correlation);
- :mod:`.force_events`: contact, punctures, pre-drops and the phases of an insertion in a force curve;
- :mod:`.shared_punctures`: the punctures the repeats share, as layers with their spread;
- :mod:`.force_metrics`: curve and event errors, per phase;
- :mod:`.repeat_statistics`: repeats of one condition, their spread and the floors they set;
- :mod:`.measured_motion`: a trial's needle travel as a pose schedule;
- :mod:`.trial_simulation`: one simulated trial as a job a worker process can run;
- :mod:`.simulated_curve`: a simulation on a trial's clock, with the scene's own punctures;
- :mod:`.puncture_spread`: the scene's spread run as simulated repeats, beside the measured one;
- :mod:`.reference_data`: the bovine-liver measurement as a study the commands read;
- :mod:`.report`: what ``compare`` writes;
- :mod:`.compare`: the command;
- :mod:`.inspect_data`: the command ``inspect``.
"""
__all__ = ['alignment', 'compare', 'force_events', 'force_metrics', 'inspect_data', 'measured_motion',
           'puncture_spread', 'reference_data', 'repeat_statistics', 'report', 'shared_punctures',
           'simulated_curve', 'trial_simulation']
