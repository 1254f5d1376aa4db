"""Running lidarflow live: predictions served per scan as it comes (Foxglove, ROS)."""
