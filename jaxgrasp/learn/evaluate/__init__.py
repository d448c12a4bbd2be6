"""What a run learned, measured: distinct grasps, the grasp atlas, ArviZ traces."""
