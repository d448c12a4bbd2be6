"""What a run starts from: demonstrations, candidate poses, rough sketches, size maps."""
