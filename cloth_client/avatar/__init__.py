"""The avatar the cloth is simulated on: capsules, pins and pose interpolation
(:mod:`~cloth_client.avatar.capsules`), knees kept apart (:mod:`~cloth_client.avatar.leg_clearance`) and
arms kept out of the trunk (:mod:`~cloth_client.avatar.limb_clearance`), with their numba kernels
(``*_kernels``)."""
