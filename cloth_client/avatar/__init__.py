"""cloth_client.avatar.capsules."""
