"""The template database: pose pruning (§2.1, :mod:`.pruning`), the shape hierarchy of Algorithm 1
(:mod:`.tree`) and the database on disk (:mod:`.database`)."""
