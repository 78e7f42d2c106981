"""Declared parameters: the pydantic base every component's ``Params`` model derives from,
and the marker for parameters that hold another component's parameters. A module of its
own so that modules the components use (matching, queries) can declare parameter models
without importing the components."""

from __future__ import annotations

import warnings
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, ClassVar

from pydantic import BaseModel, ConfigDict, PrivateAttr, model_validator


@dataclass(frozen=True)
class Removed:
    """A parameter removed or renamed, accepted for one more release (the deprecation policy,
    docs/pipelines.md): giving it warns (``DeprecationWarning``, and a plan warning at the
    step's line) with ``replacement``, what to write instead.

    ``rename``: the parameter that took its place (the value moves there unless that one is
    given too); ``None``: the value is dropped, or used by the component itself through
    :meth:`Params.removed_values`. ``accepts``: the values that still mean what the
    component does today; another value is a configuration error naming ``replacement``
    (empty: every value)."""

    replacement: str
    rename: str | None = None
    accepts: tuple[Any, ...] = ()


class Params(BaseModel):
    """Base of every component's parameter model: frozen, unknown keys rejected; the
    parameters in :attr:`removed` are still accepted, with a warning (:class:`Removed`)."""

    model_config = ConfigDict(frozen=True, extra="forbid")
    #: removed or renamed parameter -> its shim (kept one release)
    removed: ClassVar[Mapping[str, Removed]] = {}
    _removed_values: dict[str, Any] = PrivateAttr(default_factory=dict)

    @model_validator(mode="wrap")
    @classmethod
    def _shim_removed(cls, data: Any, handler: Any) -> Any:
        given: dict[str, Any] = {}
        if cls.removed and isinstance(data, Mapping):
            data = dict(data)
            for old, how in cls.removed.items():
                if old not in data:
                    continue
                value = data.pop(old)
                if how.accepts and value not in how.accepts:
                    raise ValueError(
                        f"parameter {old!r} was removed and {value!r} has no equivalent: {how.replacement}"
                    )
                given[old] = value
                warnings.warn(deprecation_message(old, how), DeprecationWarning, stacklevel=2)
                if how.rename is not None and how.rename not in data:
                    data[how.rename] = value
        model = handler(data)
        if given and isinstance(model, Params):
            model._removed_values = given
        return model

    def removed_values(self) -> dict[str, Any]:
        """The removed parameters this model was given (name -> value), for the plan's
        warnings and for a component that still honours one."""
        return dict(self._removed_values)

    def deprecations(self) -> list[str]:
        """One warning per removed parameter given (:func:`deprecation_message`)."""
        return [deprecation_message(k, type(self).removed[k]) for k in self._removed_values]


def deprecation_message(name: str, how: Removed) -> str:
    """``parameter 'plots' is deprecated and goes in the next release: <replacement>``."""
    return f"parameter {name!r} is deprecated and goes in the next release: {how.replacement}"


@dataclass(frozen=True)
class ParamsOf:
    """Marks a ``dict`` parameter as the parameters of another component (by registry key).

    ``cleaner: Annotated[dict[str, Any], ParamsOf("cleaners.mdm")] = Field(default_factory=dict)``
    keeps the value a plain dict (only the keys the user gave), and the plan validates it
    against ``cleaners.mdm``'s ``Params`` before anything runs, through the registries, so
    the declaring plugin need not import the other one.
    """

    key: str


def count_parameters(model: type[BaseModel], nested: bool = True) -> int:
    """The parameters ``model`` declares: its fields, a nested parameter model counting as
    its own fields (``nested``) rather than as one (``mocapflow plugins --count-params``)."""
    n = 0
    for field in model.model_fields.values():
        ann = field.annotation
        if nested and isinstance(ann, type) and issubclass(ann, BaseModel):
            n += count_parameters(ann, nested)
        else:
            n += 1
    return n
