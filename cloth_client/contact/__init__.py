"""Cloth against the body: round-cone geometry (:mod:`~cloth_client.contact.collision`), collision
response (:mod:`~cloth_client.contact.response`) and seam pins (:mod:`~cloth_client.contact.seam`), the
plain numpy references of the numba kernels beside them (``*_kernels``)."""
