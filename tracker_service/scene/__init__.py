"""The built-in synthetic scene: a clothed, randomly proportioned person (:mod:`.subject`) in a furnished
room (:mod:`.room`), rendered offscreen with pyrender (:mod:`.gl`, :mod:`.render`) from procedural
geometry and textures (:mod:`.geometry`, :mod:`.textures`), with the ground truth of every frame
(:mod:`.synthetic`)."""
