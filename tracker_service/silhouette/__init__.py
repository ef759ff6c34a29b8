"""tracker_service.silhouette."""
