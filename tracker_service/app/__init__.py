"""The world's edge of the tracker: the command line (:mod:`.cli`, one module per command in
:mod:`.commands`, options in :mod:`.options`), the daemon (:mod:`.daemon`), replay, evaluation,
recording, rendering and the demo. Nothing below this package sees ``argparse``."""
