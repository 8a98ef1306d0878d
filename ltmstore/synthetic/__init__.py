"""Ground-truth scenes, handheld trajectories and simulated acquisitions."""
