"""``python -m tracker_service``: the same as the ``mocap-tracker`` command."""

import sys

from tracker_service.app.entry import main

if __name__ == "__main__":
    sys.exit(main())
