"""Video in and out: the result drawn over the footage (:func:`~chainspace.video.overlay.draw_overlay`)."""
