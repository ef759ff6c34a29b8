"""protocol.net."""
