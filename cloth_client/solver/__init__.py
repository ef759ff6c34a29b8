"""The cloth solver: garments (:mod:`~cloth_client.solver.garment`, :mod:`~cloth_client.solver.grid`), the
model and state (:mod:`~cloth_client.solver.model`), the step (:mod:`~cloth_client.solver.cloth`), its numba
kernels (``*_kernels``) with their numpy references (:mod:`~cloth_client.solver.reference`), and the
driver that feeds it poses (:mod:`~cloth_client.solver.driver`)."""
