"""A robot on ROS 2: its pose from a ROS 2 topic, its command as ``geometry_msgs/Twist``.

Imported only by a robot started with ``--ros2`` (``rclpy`` is loaded when the link opens),
so a robot without ROS 2 stays light. Needs the ``ros2`` extra.
"""
