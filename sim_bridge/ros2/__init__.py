"""The world's side of ROS 2: the simulated robots as a ROS 2 fleet (``sim --ros2``) and logs
as rosbag2 folders (``replay --to-rosbag2``). Needs the ``ros2`` extra."""
