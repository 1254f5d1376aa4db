"""Live prediction on a running robot: the per-scan step, the ROS 1 node and the Foxglove
server."""
