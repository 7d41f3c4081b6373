"""ament_formation: sliding-mode formation control with elliptical limit-cycle avoidance (ROS 2 Jazzy)."""

__version__ = "0.1.0"
