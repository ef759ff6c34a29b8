"""tracker_service.build."""
