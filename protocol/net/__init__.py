"""Networking helpers: Zenoh configuration and sessions from ``--mode/--connect/--listen/--config``
(:mod:`.session`) and shared argument types (:mod:`.cli_args`)."""
