"""cloth_client.app.live."""
