"""cloth_client.solver."""
