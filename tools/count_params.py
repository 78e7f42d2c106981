"""Count the parameters every registered component declares (its ``Params`` fields).

    python tools/count_params.py [--nested] [--by-component]

Top-level fields by default; ``--nested`` also counts the fields of nested parameter models
(a sub-model field counts as its own fields, not as one).
"""

from __future__ import annotations

import argparse

from pydantic import BaseModel

from mocapflow.framework import get_plugin_manager
from mocapflow.framework.plugins import build_registries


def count_fields(model: type[BaseModel], nested: bool) -> int:
    n = 0
    for field in model.model_fields.values():
        ann = field.annotation
        if nested and isinstance(ann, type) and issubclass(ann, BaseModel):
            n += count_fields(ann, nested)
        else:
            n += 1
    return n


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--nested", action="store_true", help="count nested parameter models' fields")
    ap.add_argument("--by-component", action="store_true", help="one line per component")
    args = ap.parse_args(argv)
    regs = build_registries(get_plugin_manager(entry_points=False))
    total, comps = 0, 0
    for kind, registry in regs.by_kind.items():
        for name, cls in registry:
            params = getattr(cls, "Params", None)
            if params is None or not (isinstance(params, type) and issubclass(params, BaseModel)):
                continue
            n = count_fields(params, args.nested)
            if n == 0:
                continue
            comps += 1
            total += n
            if args.by_component:
                print(f"{kind}.{name:<24} {n:4d}")
    print(f"{comps} components declare {total} parameters")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
