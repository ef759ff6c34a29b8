"""tracker_service.body."""
