"""Cloth client: an avatar built from a tracker's ``BodyInfo``, posed by its ``PoseFrame`` stream and
dressed in a simulated garment (Okada & Stenger, section 4, "virtual clothing").

Subpackages, each depending only on those before it: :mod:`~cloth_client.contact` (body capsules:
geometry, collision response, seam pins), :mod:`~cloth_client.avatar` (capsules and pins from poses,
limbs kept apart and out of the trunk), :mod:`~cloth_client.solver` (garments, mass-spring solver,
the driver: dressing, interpolation, resets, metrics) and :mod:`~cloth_client.app` (recorded runs,
pyrender view, Zenoh client and the ``mocap-cloth`` command). Every numba kernel sits in a
``*_kernels`` module beside its plain numpy reference (``<kernel>_reference``); the decorators are in
:mod:`cloth_client._jit`.
"""
