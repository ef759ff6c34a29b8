"""The ``mocap-cloth`` application: command line (:mod:`~cloth_client.app.cli`), recorded runs
(:mod:`~cloth_client.app.offline`), the live Zenoh client (:mod:`~cloth_client.app.live`) and the
pyrender view (:mod:`~cloth_client.app.render`)."""
