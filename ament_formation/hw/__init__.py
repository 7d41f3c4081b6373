"""Hardware-facing helpers that are not ROS nodes (pty runner of the emulated motor board)."""
