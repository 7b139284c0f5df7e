"""Recordings, read and written: every file format wftool keeps a stream in (ROS 2 bags,
JSON MCAP, CSV, the MSP baseline's bag) and the ROS 2 messages they hold."""
