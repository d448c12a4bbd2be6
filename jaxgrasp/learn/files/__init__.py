"""What a run writes and reads: atomic files, checkpoints, results, grasp files, HTML views."""
