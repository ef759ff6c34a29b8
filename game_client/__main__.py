"""``python -m game_client`` runs ``mocap-game``."""

from .cli import main

raise SystemExit(main())
