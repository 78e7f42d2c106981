"""Self-similarity cleaning after Aristidou et al. 2018: motion words, digression maps,
the MDM cleaner and its evaluation protocol. :mod:`.plugin` registers them."""
