"""The host-speed probe the benchmarks record (:mod:`tracker_service.app.host_probe`)."""

from tracker_service.app.host_probe import host_probe

__all__ = ["host_probe"]
