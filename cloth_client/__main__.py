"""``python -m cloth_client``: the ``mocap-cloth`` command line (see :mod:`cloth_client.cli`)."""

from .cli import main

raise SystemExit(main())
