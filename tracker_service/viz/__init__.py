"""Drawing the tracker's view for people: the overlay of the silhouette, the projected skeleton and a
HUD on the camera frame (:mod:`tracker_service.viz.overlay`)."""
