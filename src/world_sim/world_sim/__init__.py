"""The physical world of uav-flock: MAP dynamics, ground users, association, metrics, and the batch simulator."""
