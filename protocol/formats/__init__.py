"""protocol.formats."""
