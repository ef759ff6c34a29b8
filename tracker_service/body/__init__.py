"""Bodies: the family of 30 models (:mod:`.family`), bodies from measurements (:mod:`.measured`),
proportions read from the appearance cue (:mod:`.proportions`), the capsule rasteriser that draws
templates (:mod:`.raster`) and triangle meshes of capsule bodies (:mod:`.mesh`)."""
