"""From frame to silhouette evidence: background subtraction (§2.2, :mod:`.background`), the image
pyramid and distance transforms (eq. 9-12, :mod:`.features`), template distances XOR / cwXOR /
nwXOR (eq. 7-12, :mod:`.distance`) and the global placement from the feet line (:mod:`.placement`)."""
