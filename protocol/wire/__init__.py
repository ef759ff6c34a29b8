"""protocol.wire."""
