"""ROS 2, live: the node that publishes the FSP stream and takes commands (`wftool ros2`),
and the wftool_msgs type support it needs (the `ros2` extra)."""
