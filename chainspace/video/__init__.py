"""Video: rendering a robot, markers, and (other modules) tracking and overlays."""
