"""Self-similarity cleaning after Aristidou et al. 2018 (``cleaners.mdm``, ``analyses.clean_eval``,
``mocapflow clean``): :mod:`.paper` (motion words, KNN, the digression map, the paper's
repair), :mod:`.calibrated` (the default decision and its bounded repair), :mod:`.evaluation`
(error injection and the protocol). :mod:`.cleaner` is the component, :mod:`.plugin` registers."""
