"""Per-MAP mathematics of the paper, free of ROS: the node and the batch simulator both call these."""
