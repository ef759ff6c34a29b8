"""Okada & Stenger's tree-based Bayesian filter (§2, eq. 1-6, 13-14): :mod:`.filter` (the step and
:class:`~.filter.TreeFilter`), :mod:`.model` (database, parameters, state), numba kernels beside
their numpy references (:mod:`._kernels`, :mod:`.reference`)."""
