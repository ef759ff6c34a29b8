"""The hierarchical particle filter of the upper-body cardbox paper (DRS and SRS resampling)."""

from tracker_service.estimators.hierarchical_pf.filter import (
    DEFAULT_STAGES,
    HierarchicalPF,
    HPFParams,
    HPFState,
    Stage,
)

__all__ = ["DEFAULT_STAGES", "HPFParams", "HPFState", "HierarchicalPF", "Stage"]
