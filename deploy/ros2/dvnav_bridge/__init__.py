"""dvnav's ROS 2 bridge: drives a robot with `dvnav serve` from its LaserScan and odometry."""
