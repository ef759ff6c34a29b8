"""The virtual-clothing front-end: an avatar that follows the tracked poses, dressed in simulated cloth."""
