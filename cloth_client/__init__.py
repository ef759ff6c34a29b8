"""Cloth client: an avatar built from a tracker's ``BodyInfo``, posed by its ``PoseFrame`` stream and
dressed in a simulated garment (Okada & Stenger, section 4, "virtual clothing").

Modules: :mod:`~cloth_client.solver.garment` (parametric cape / skirt sized to the body),
:mod:`~cloth_client.solver.cloth` (mass-spring solver), :mod:`~cloth_client.contact.collision` (body capsules),
:mod:`~cloth_client.avatar.capsules` (capsules and pins from poses), :mod:`~cloth_client.solver.driver` (dressing,
interpolation, resets, metrics), :mod:`~cloth_client.app.offline` (recorded runs),
:mod:`~cloth_client.app.render` (pyrender view), :mod:`~cloth_client.app.live` and
:mod:`~cloth_client.app.cli` (Zenoh client and ``mocap-cloth`` command).
"""
