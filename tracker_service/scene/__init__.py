"""tracker_service.scene.synthetic."""
