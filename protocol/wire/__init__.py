"""What goes over the wire: messages (:mod:`.messages`, :mod:`.game_messages`), the strict msgpack
codec (:mod:`.codec`), key expressions (:mod:`.keys`) and the checks by meaning a client applies to
what it receives (:mod:`.validate`)."""
