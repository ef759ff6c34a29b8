"""``python -m cloth_client``: the ``mocap-cloth`` command line (see :mod:`cloth_client.app.cli`)."""

from cloth_client.app.cli import main

raise SystemExit(main())
