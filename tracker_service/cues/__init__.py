"""Evidence beyond the silhouette, each observing the frame and scoring template leaves: skin for the
hands (:mod:`.skin`), shoes for the feet (:mod:`.shoes`), the appearance network for the joints'
depth (:mod:`.appearance`, its readings filtered over time by :mod:`.reading_filter`)."""
