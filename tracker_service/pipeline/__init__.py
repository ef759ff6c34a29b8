"""tracker_service.pipeline.process."""
