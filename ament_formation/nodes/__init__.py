"""One rclpy node per module; each is thin: message in, one core call, message out."""
