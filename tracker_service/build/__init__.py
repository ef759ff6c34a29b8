"""Offline builds: the template database (:mod:`.database`), the appearance network's training
(:mod:`.appearance_train`, :mod:`.posture_variation`) and the shipped network's card
(:mod:`.model_card`)."""
