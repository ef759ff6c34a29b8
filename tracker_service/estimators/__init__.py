"""tracker_service.estimators."""
