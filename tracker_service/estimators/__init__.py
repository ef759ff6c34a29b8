"""Pose estimators behind one interface (:mod:`tracker_service.estimators.base`).

``tree`` (Okada & Stenger's tree-based filter over the template hierarchy, the default),
``condensation`` (Isard & Blake's particle filter, the baseline), ``drs`` / ``srs`` (the
hierarchical particle filter of the cardbox paper with deterministic or stratified resampling;
``drs-cardbox`` / ``srs-cardbox`` with the paper's 3D cardbox body model) and
``elmo`` (Demirdjian et al.'s exploration of likelihood modes: parameter-sensitive hashing over the
database's leaves, local refinement, reweighting by a wide temporal prior); ``tree-elmo`` (the tree
filter's estimate refined to the nearest likelihood mode, ELMO's §3.2-3.3 seeded by the tree).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from protocol.skeleton import Body
from tracker_service.camera import Camera
from tracker_service.estimators.tree_filter.model import FilterDB, FilterParams

__all__ = ["ESTIMATORS", "make_estimator"]

#: The estimators ``--estimator`` accepts.
ESTIMATORS = ("tree", "tree-elmo", "condensation", "drs", "srs", "elmo", "drs-cardbox", "srs-cardbox")


def make_estimator(name: str, db: FilterDB, body: Body, camera: Camera, params: FilterParams,
                   seed: int = 0) -> Any:
    """The estimator called ``name``.

    Parameters
    ----------
    name : one of ESTIMATORS
    db : FilterDB
        The template database (the tree filter searches it).
    body : Body
        The database's body (the particle filters render it).
    camera : Camera
        The database's camera.
    params : FilterParams
        The tree filter's tuning.
    seed : int
        The particle filters' random stream (ELMO's: learning its hash functions).

    Returns
    -------
    Estimator
    """
    from tracker_service.estimators.tree_filter.filter import TreeFilter

    if name == "tree":
        return TreeFilter(db, params)
    if name == "tree-elmo":
        from tracker_service.estimators.tree_elmo import TreeElmo

        return TreeElmo(db, body, camera, params)
    rng = np.random.default_rng(seed)
    if name == "condensation":
        from tracker_service.estimators.condensation import Condensation

        return Condensation(body, camera, rng=rng)
    if name in ("drs", "srs", "drs-cardbox", "srs-cardbox"):
        from tracker_service.body.cardbox import CardboxModel
        from tracker_service.estimators.hierarchical_pf import HierarchicalPF, HPFParams

        cardbox = CardboxModel.from_body(body) if name.endswith("-cardbox") else None
        return HierarchicalPF(body, camera, HPFParams(resampling="drs" if name.startswith("drs") else "srs",
                                                      cardbox=cardbox), rng=rng)
    if name == "elmo":
        from tracker_service.estimators.elmo import Elmo

        return Elmo(db, body, camera, rng=rng)
    raise ValueError(f"unknown estimator {name!r}; choose from {', '.join(ESTIMATORS)}")
