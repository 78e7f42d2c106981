"""Registration of the Aristidou et al. 2018 components (the ``selfsim`` package): the
``cleaners.mdm`` cleaner (motion-word self-similarity, digression maps, repair), the
``analyses.clean_eval`` protocol and the ``mocapflow clean`` command. Imports happen inside
the hooks, so loading this module imports no numerical library."""

from __future__ import annotations

from mocapflow.framework.plugins import hookimpl


@hookimpl
def register_cleaners() -> list[type]:
    from .cleaner import MDMCleaner

    return [MDMCleaner]


@hookimpl
def register_analyses() -> list[type]:
    from .evaluation.clean_eval import CleaningEvaluation

    return [CleaningEvaluation]


@hookimpl
def register_commands() -> list[type]:
    from .clean_command import CleanCommand

    return [CleanCommand]
