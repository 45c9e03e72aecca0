"""What the runs keep: the SQLite run store (:mod:`~sssbench.store.tracking`), the exact
reference cache keyed by content (:mod:`~sssbench.store.refcache`) and the optional MLflow
mirror (:mod:`~sssbench.store.mlflow_mirror`). Both the runner and the report reach it."""
