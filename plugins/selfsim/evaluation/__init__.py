"""Evaluation of the cleaner: seeded error injection, the protocol of ``analyses.clean_eval``
and its scores."""
