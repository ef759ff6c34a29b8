"""Cloth client: an avatar built from a tracker's ``BodyInfo``, posed by its ``PoseFrame`` stream and
dressed in a simulated garment (Okada & Stenger, section 4, "virtual clothing").

Modules: :mod:`~cloth_client.garment` (parametric cape / skirt sized to the body),
:mod:`~cloth_client.cloth` (mass-spring solver), :mod:`~cloth_client.collision` (body capsules),
:mod:`~cloth_client.avatar` (capsules and pins from poses), :mod:`~cloth_client.driver` (dressing,
interpolation, resets, metrics), :mod:`~cloth_client.offline` (recorded runs),
:mod:`~cloth_client.render` (pyrender view), :mod:`~cloth_client.app` and
:mod:`~cloth_client.cli` (Zenoh client and ``mocap-cloth`` command).
"""
