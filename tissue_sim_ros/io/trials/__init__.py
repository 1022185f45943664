"""Load-cell recordings as trials in SI units (REP 103), whatever their columns and units.

- :mod:`.measurement_units`: units of recordings and their factors to SI;
- :mod:`.trial`: one measured insertion (time, axial force, travel, torque) in SI;
- :mod:`.text_files`: a CSV, TSV or whitespace-separated recording as a trial;
- :mod:`.mcap_files`: a robot's rosbag2 MCAP recording as a trial;
- :mod:`.data_spec_keys`: every key of a data description, with its checks;
- :mod:`.data_spec`: a study's files described once and loaded as trials.
"""
__all__ = ['data_spec', 'data_spec_keys', 'mcap_files', 'measurement_units', 'text_files', 'trial']
