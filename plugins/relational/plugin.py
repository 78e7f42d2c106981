"""Plugin registering the relational-feature retrieval components (Müller et al. 2005):
``features.relational``, ``indexes.inverted`` and ``matchers.relational``; and the motion
templates of Müller & Röder 2006: ``matchers.template`` and ``analyses.classify``."""

from __future__ import annotations

from mocapflow.framework.plugins import hookimpl


@hookimpl
def register_features() -> list[type]:
    from .features import RelationalFeatures

    return [RelationalFeatures]


@hookimpl
def register_indexes() -> list[type]:
    from .inverted import InvertedIndex

    return [InvertedIndex]


@hookimpl
def register_matchers() -> list[type]:
    from .matcher import RelationalMatcher
    from .template import TemplateMatcher

    return [RelationalMatcher, TemplateMatcher]


@hookimpl
def register_analyses() -> list[type]:
    from .classify import TemplateClassifier

    return [TemplateClassifier]
