"""rclpy shells around the core simulator: the node, the pose player, the recorder.

``pose_input`` and ``scheduler`` are pure (no rclpy), so their logic is unit-tested
without ROS; the node modules only translate messages, own timers, QoS and parameters.
"""
