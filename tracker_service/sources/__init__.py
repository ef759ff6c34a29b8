"""Frames in: a camera, a video file, a folder of images or the synthetic scene behind one interface
(:mod:`.frame_source`), any frame size fitted to the working size without stretching."""
