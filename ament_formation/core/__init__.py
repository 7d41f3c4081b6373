"""ROS-free, pure computation: dynamics, control laws, switching, rewiring, scenarios, simulator,
metrics, serial codec and camera model. Nothing here imports rclpy or ROS messages (a test enforces
it).
"""
