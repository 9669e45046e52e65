"""The physical world of the paper, free of ROS: the world node and the batch simulator both call these."""
