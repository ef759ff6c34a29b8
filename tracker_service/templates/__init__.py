"""tracker_service.templates."""
