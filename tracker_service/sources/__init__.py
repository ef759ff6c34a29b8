"""tracker_service.sources.frame_source."""
