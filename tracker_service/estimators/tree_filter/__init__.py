"""tracker_service.estimators.tree_filter."""
