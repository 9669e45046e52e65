"""One MAP of the formation: the per-MAP control law and mode switch, and its rclpy node."""
