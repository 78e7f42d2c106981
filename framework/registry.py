"""Registries: name -> component class, one per component kind."""

from __future__ import annotations

import difflib
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from .errors import ConfigError, PluginError
from .joints import JointMap

#: The component kinds, in the order ``mocapflow plugins`` lists them.
KINDS: tuple[str, ...] = ("formats", "features", "indexes", "matchers", "cleaners", "analyses")


def did_you_mean(name: str, candidates: list[str] | tuple[str, ...] | set[str]) -> str:
    """``" (did you mean 'x'?)"`` for the closest candidate, or ``""``."""
    close = difflib.get_close_matches(name, sorted(candidates), n=1, cutoff=0.5)
    return f" (did you mean {close[0]!r}?)" if close else ""


def known_names(names: list[str], limit: int = 12) -> str:
    """``names`` joined by commas, or, past ``limit`` of them, the first ones and a count
    (an error message stays readable when a model has dozens of parameters)."""
    if len(names) <= limit:
        return ", ".join(names) or "none"
    return f"{', '.join(names[:limit])}, ... ({len(names)} in all; `mocapflow plugins` lists them)"


def params_error(owner: str, exc: Any, model: Any, prefix: tuple[str, ...] = ()) -> tuple[tuple[str, ...], str]:
    """``(location, message)`` of the first error of a pydantic ``ValidationError`` ``exc``
    raised by ``model`` (a ``Params``) for component ``owner``: the parameter by name, what
    was wrong and, for an unknown one, the closest and the known names."""
    err = exc.errors()[0]
    inner = tuple(str(p) for p in err["loc"])
    loc = (*prefix, *inner)
    key = ".".join(loc) or "with"
    if err["type"] == "extra_forbidden":
        holder = model
        for part in inner[:-1]:  # the nested model that holds the unknown key
            f = holder.model_fields.get(part) if holder is not None else None
            ann = f.annotation if f is not None else None
            holder = ann if isinstance(ann, type) and hasattr(ann, "model_fields") else None
        known = list(holder.model_fields) if holder is not None else []
        return loc, f"unknown parameter {key!r} for {owner}{did_you_mean(loc[-1], known)}; known: {known_names(known)}"
    return loc, f"parameter {key!r} of {owner}: {err['msg']} (got {err.get('input')!r})"


@dataclass
class Registry:
    """Components of one kind by ``name``, with the plugin that provided each (for errors)."""

    kind: str
    _classes: dict[str, type[Any]] = field(default_factory=dict)
    _providers: dict[str, str] = field(default_factory=dict)

    def check(self, cls: type[Any], provider: str) -> None:
        """Raise :class:`PluginError` unless ``cls`` may be registered here (a snake_case
        ``name`` and, if it declares one, this ``kind``)."""
        name = getattr(cls, "name", None)
        if not isinstance(name, str) or not name.isidentifier() or name != name.lower():
            raise PluginError(f"plugin {provider!r} registered {cls!r} under {self.kind} without a snake_case `name`")
        if getattr(cls, "kind", self.kind) != self.kind:
            raise PluginError(f"plugin {provider!r} registered {cls.__name__} ({cls.kind}) as one of the {self.kind}")
        from .params import Params  # pydantic: not on the way of `mocapflow --help`

        declared = getattr(cls, "Params", None)
        if not (isinstance(declared, type) and issubclass(declared, Params)):
            raise PluginError(f"plugin {provider!r} registered {cls.__name__} without a `Params` model")

    def add(self, cls: type[Any], provider: str) -> None:
        self.check(cls, provider)
        name = cls.name
        if name in self._classes and self._classes[name] is not cls:
            raise PluginError(
                f"duplicate {self.kind} component {name!r}: provided by plugin {self._providers[name]!r} "
                f"and by plugin {provider!r}"
            )
        self._classes[name] = cls
        self._providers[name] = provider

    def get(self, name: str) -> type[Any]:
        try:
            return self._classes[name]
        except KeyError:
            raise ConfigError(
                f"unknown {self.kind} component {name!r}{did_you_mean(name, list(self._classes))}"
            ) from None

    def provider(self, name: str) -> str:
        return self._providers[name]

    def names(self) -> list[str]:
        return sorted(self._classes)

    def __contains__(self, name: object) -> bool:
        return name in self._classes

    def __iter__(self) -> Iterator[tuple[str, type[Any]]]:
        return iter(sorted(self._classes.items()))

    def __len__(self) -> int:
        return len(self._classes)


@dataclass
class Registries:
    """All registries of one plugin manager, addressed by kind or by ``kind.name`` keys."""

    by_kind: dict[str, Registry] = field(default_factory=lambda: {k: Registry(k) for k in KINDS})
    #: Executor classes (``register_executors``) by name; not components, so not in ``by_kind``.
    executors: Registry = field(default_factory=lambda: Registry("executors"))
    #: Skeleton naming dialects (``register_joint_maps``) by name, and the plugin of each.
    joint_maps: dict[str, JointMap] = field(default_factory=dict)
    joint_map_providers: dict[str, str] = field(default_factory=dict)

    def __getitem__(self, kind: str) -> Registry:
        return self.by_kind[kind]

    def resolve(self, key: str) -> type[Any]:
        """Class for a ``<kind>.<name>`` key, with "did you mean" on typos."""
        kind, _, name = key.partition(".")
        if kind not in self.by_kind or not name:
            every = [f"{k}.{n}" for k, r in self.by_kind.items() for n in r.names()]
            raise ConfigError(
                f"unknown component {key!r}: expected '<kind>.<name>' with kind one of {', '.join(KINDS)}{did_you_mean(key, every)}"
            )
        registry = self.by_kind[kind]
        if name not in registry:
            every = [f"{kind}.{n}" for n in registry.names()]
            raise ConfigError(f"unknown component {key!r}{did_you_mean(key, every)}")
        return registry.get(name)

    def motion_format(self, path: str | Path, *, writing: bool = False) -> Any:
        """An instance of the registered motion format for the extension of ``path``
        (a writer when ``writing``); :class:`ConfigError` when none handles it."""
        ext = Path(path).suffix.lower()
        for _, cls in self.by_kind["formats"]:
            if ext in cls.extensions and cls.produces == "motion" and (not writing or cls.can_write()):
                return cls()
        exts = sorted({e for _, c in self.by_kind["formats"] for e in c.extensions if c.produces == "motion"})
        what = f"{ext!r} files" if ext else "a path without a file extension"
        if Path(path).is_dir():
            what = "a folder (give a file, or the folder's files: a list or a glob)"
        raise ConfigError(
            f"{path}: no registered {'writer' if writing else 'reader'} for {what}; motion files: {', '.join(exts)}"
        )

    def keys(self) -> list[str]:
        return [f"{k}.{n}" for k, r in self.by_kind.items() for n in r.names()]
