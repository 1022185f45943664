"""Unit constants shared by every layer (REP 103: SI everywhere; ROS stamps are integer ns).

One home for each, so that no module writes its own copy of a conversion factor.
"""
#: Nanoseconds per second: ROS 2 stamps, MCAP log times and the node clock are integer ns.
NS_PER_S = 1_000_000_000
