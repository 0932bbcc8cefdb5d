"""Video in and out: reading frames, key frames of the chain's points, tracking them, picking them by
hand, and the result drawn over the footage.

* :mod:`chainspace.video.reader`: :func:`open_video` streams the frames of an MP4/MOV/AVI file or of a
  folder of numbered images (OpenCV), one at a time.
* :mod:`chainspace.video.writer`: :func:`frame_writer` writes frames to an MP4 or a folder of PNGs,
  atomically and never over an existing output unless asked: the renderer's and the overlay's writer.
* :mod:`chainspace.video.keyframes`: the key-frame JSON (frame index -> point name -> pixel).
* :mod:`chainspace.video.tracking`: :func:`track_points` follows the points through the video with
  pyramidal Lucas-Kanade and a forward-backward check; :func:`track_video` is the file-to-file twin of
  ``chainspace track``.
* :mod:`chainspace.video.picker`: a standalone HTML page to click the points on a frame
  (``chainspace pick``).
* :mod:`chainspace.video.markers`: ArUco markers stuck on a robot's links (a marker map file), found in
  every frame and turned into tracks of the chain (``chainspace markers``).
* :mod:`chainspace.video.render`: a robot filmed by a pinhole camera, rendered with pybullet's CPU
  renderer (textured links, markers, lens distortion) with the true pixels beside it: test footage
  and the demo's video.
* :mod:`chainspace.video.overlay`: :func:`draw_overlay` draws a fit or a reconstruction, reprojected
  through its own camera, over every frame (``chainspace overlay``).

The public names are re-exported from :mod:`chainspace`; submodules import OpenCV only when used.
"""
