"""Task layer: action spaces, perception (candidate points, sight, LiDAR), observations,
planner and bots."""
