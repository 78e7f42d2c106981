"""Built-in executors: ``local`` (in-process or a process pool) and ``dask``. :mod:`.plugin`
registers them."""
