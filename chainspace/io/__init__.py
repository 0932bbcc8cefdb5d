"""Files in and out: robot and skeleton descriptions, 2D tracks, results, the bundled motion data."""
