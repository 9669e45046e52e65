"""ROS 2 plumbing every uav-flock node shares: QoS profiles, the executor and stop signals, message conversions, process checks."""
