"""``tissue-sim compare``: the simulation on the measured motion of load-cell trials.

- :mod:`.alignment`: two force records on one time base (resampling, cross-correlation);
- :mod:`.force_events`: contact, punctures and the phases of an insertion in a force curve;
- :mod:`.force_metrics`: curve and event errors, per phase;
- :mod:`.repeat_statistics`: repeats of one condition, their spread and the floors they set;
- :mod:`.measured_motion`: a trial's needle travel as a pose schedule;
- :mod:`.trial_simulation`: one simulated trial as a job a worker process can run;
- :mod:`.reference_data`: the bovine-liver measurement as a study the commands read;
- :mod:`.report`: what ``compare`` writes;
- :mod:`.compare`: the command.
"""
__all__ = ['alignment', 'compare', 'force_events', 'force_metrics', 'measured_motion', 'reference_data',
           'repeat_statistics', 'report', 'trial_simulation']
