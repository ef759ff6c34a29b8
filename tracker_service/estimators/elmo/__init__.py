"""ELMO (Demirdjian, Taycher, Shakhnarovich, Grauman & Darrell 2005): tracking by exploring
likelihood modes.

* :mod:`.hashing` -- §3.1, parameter-sensitive hashing over the database leaves' silhouettes;
* :mod:`.refine` -- §3.2, local refinement of each hypothesis (pattern search of the silhouette
  likelihood) and the mode's covariance;
* :mod:`.modes` -- eq. 3's mixture of modes and §3.3's reweighting by a wide temporal prior (eq. 6);
* :mod:`.filter` -- :class:`Elmo`, the estimator.
"""

from tracker_service.estimators.elmo.filter import Elmo, ElmoParams, ElmoState
from tracker_service.estimators.elmo.hashing import PSHIndex, PSHParams, build_index
from tracker_service.estimators.elmo.modes import Modes, merge_modes, reweight

__all__ = ["Elmo", "ElmoParams", "ElmoState", "Modes", "PSHIndex", "PSHParams", "build_index", "merge_modes",
           "reweight"]
