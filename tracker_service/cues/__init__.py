"""tracker_service.cues."""
