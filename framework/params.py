"""Declared parameters: the pydantic base every component's ``Params`` model derives from,
and the marker for parameters that hold another component's parameters. A module of its
own so that modules the components use (matching, queries) can declare parameter models
without importing the components."""

from __future__ import annotations

from dataclasses import dataclass

from pydantic import BaseModel, ConfigDict


class Params(BaseModel):
    """Base of every component's parameter model: frozen, unknown keys rejected."""

    model_config = ConfigDict(frozen=True, extra="forbid")


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
