"""cloth_client.contact.response."""
