"""tracker_service.app."""
