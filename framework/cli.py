"""The ``mocapflow`` command line: run, plan, plugins, sql, plus plugin commands.

Errors a user can fix are printed as one line (exit 2 for configuration problems, 1 for
failures while running); ``--debug`` shows tracebacks.
"""
from __future__ import annotations

import argparse
import logging
import sys
import traceback
from pathlib import Path
from .errors import ConfigError, MocapflowError, PluginError

BUILTIN_COMMANDS = ("run", "plan", "plugins", "sql")


def _echo(msg: str) -> None:
    print(msg, flush=True)


def cmd_run(args: argparse.Namespace, pm) -> int:
    from .runner import run_pipeline

    _echo(f"mocapflow: running {args.pipeline}")
    reports = run_pipeline(args.pipeline, workspace=args.workspace, overrides=args.set, jobs=args.jobs,
                           force=args.force, pm=pm, echo=_echo)
    computed = sum(r.status == "computed" for r in reports)
    fresh = len(reports) - computed
    if computed == 0:
        _echo(f"nothing to do: all {fresh} steps up to date")
    else:
        _echo(f"done: {computed} computed, {fresh} up to date")
    return 0


def cmd_plan(args: argparse.Namespace, pm) -> int:
    import json

    from .plugins import build_registries
    from .runner import default_workspace, plan_pipeline

    plan = plan_pipeline(args.pipeline, args.set, registries=build_registries(pm))
    ws = Path(args.workspace).resolve() if args.workspace else default_workspace(plan)
    fps = plan.fingerprints()
    _echo(f"pipeline {plan.source.config.name!r}: {len(plan.steps)} steps, workspace {ws}")
    for s in plan.steps:
        manifest = ws / s.step_id / "_manifest.json"
        state = "would compute"
        if manifest.is_file():
            try:
                state = "up to date" if json.loads(manifest.read_text()).get("fingerprint") == fps[s.step_id] else "would recompute"
            except ValueError:
                pass
        ins = ", ".join(f"{k}<-{v}" for k, v in s.inputs.items()) or "-"
        _echo(f"  {s.step_id:<16} {s.key:<28} inputs: {ins:<30} [{state}]")
        for k, v in s.component.get_params().items():
            _echo(f"      {k} = {v!r}")
    _echo("plan is valid")
    return 0


def _param_rows(cls: type) -> list[str]:
    rows = []
    for name, field in cls.Params.model_fields.items():
        default = "required" if field.is_required() else f"default {field.get_default(call_default_factory=True)!r}"
        desc = f" - {field.description}" if field.description else ""
        ann = getattr(field.annotation, "__name__", None) or str(field.annotation).replace("typing.", "")
        rows.append(f"        {name}: {ann} ({default}){desc}")
    return rows


def cmd_plugins(args: argparse.Namespace, pm) -> int:
    from .plugins import build_registries
    from .registry import KINDS

    regs = build_registries(pm)
    by_plugin: dict[str, list[tuple[str, type]]] = {}
    for kind in KINDS:
        for name, cls in regs[kind]:
            by_plugin.setdefault(regs[kind].provider(name), []).append((f"{kind}.{name}", cls))
    for plugin in sorted(by_plugin):
        _echo(plugin)
        for key, cls in by_plugin[plugin]:
            doc = (cls.__doc__ or "").strip().splitlines()
            _echo(f"    {key}  ({cls.__module__}.{cls.__name__}, v{cls.version}){' - ' + doc[0] if doc else ''}")
            _echo("\n".join(_param_rows(cls)) or "        (no parameters)")
    for f in getattr(pm, "failures", []):
        _echo(f"BROKEN plugin {f.plugin!r}: {f.error}")
    return 0


def cmd_sql(args: argparse.Namespace, pm) -> int:
    from .catalog import Catalog, format_table, write_table

    with Catalog(args.workspace) as cat:
        if not args.query:
            _echo("views: " + ", ".join(sorted(cat.views)))
            return 0
        table = cat.query(args.query, args.param or None)
    if args.output:
        fmt = args.format if args.format != "table" else Path(args.output).suffix.lstrip(".") or "csv"
        write_table(table, args.output, fmt)
        _echo(f"wrote {table.num_rows} rows to {args.output}")
    elif args.format == "csv":
        import io

        import pyarrow.csv as pacsv

        from .catalog import CSV_OPTIONS

        buf = io.BytesIO()
        pacsv.write_csv(table, buf, CSV_OPTIONS())
        sys.stdout.write(buf.getvalue().decode())
    elif args.format == "parquet":
        raise ConfigError("--format parquet needs --output FILE")
    else:
        _echo(format_table(table, max_rows=args.max_rows))
    return 0


def build_parser(plugin_commands: list[type]) -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="mocapflow", description="Searchable, clean motion-capture databases.")
    parser.add_argument("--debug", action="store_true", help="show tracebacks and debug logging")
    parser.add_argument("--no-entry-points", action="store_true", help="do not load third-party plugins")
    parser.add_argument("--block", action="append", default=[], metavar="PLUGIN", help="do not load this plugin")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")

    def common(p: argparse.ArgumentParser) -> None:
        p.add_argument("pipeline", help="pipeline YAML file")
        p.add_argument("--workspace", help="output directory (default: the pipeline's `workspace`)")
        p.add_argument("--set", action="append", default=[], metavar="STEP.KEY=VALUE", help="override a step parameter")

    p = sub.add_parser("run", help="run a pipeline (steps whose inputs and parameters are unchanged are skipped)")
    common(p)
    p.add_argument("--jobs", "-j", type=int, default=None, help="worker processes for per-clip work (0 = all cores)")
    p.add_argument("--force", action="store_true", help="recompute every step")
    p.set_defaults(func=cmd_run)

    p = sub.add_parser("plan", help="validate a pipeline and show what would run")
    common(p)
    p.set_defaults(func=cmd_plan)

    p = sub.add_parser("plugins", help="list plugins, their components and parameters")
    p.set_defaults(func=cmd_plugins)

    p = sub.add_parser("sql", help="query a workspace with DuckDB (one view per dataset, plus clips)")
    p.add_argument("workspace")
    p.add_argument("query", nargs="?", help="SELECT ... (omit to list the views)")
    p.add_argument("--param", action="append", default=[], help="value for a ? placeholder (repeatable)")
    p.add_argument("--format", choices=("table", "csv", "parquet"), default="table")
    p.add_argument("--output", "-o", help="write the result to this file (csv or parquet)")
    p.add_argument("--max-rows", type=int, default=50)
    p.set_defaults(func=cmd_sql)

    for cls in plugin_commands:
        if cls.name in BUILTIN_COMMANDS:
            raise PluginError(f"plugin command {cls.name!r} ({cls.__module__}) clashes with a built-in command")
        p = sub.add_parser(cls.name, help=getattr(cls, "help", ""))
        cls.add_arguments(p)
        # the command sees the plugin manager built here (--block, --no-entry-points) as args.plugin_manager
        p.set_defaults(func=lambda a, pm, _cls=cls: (setattr(a, "plugin_manager", pm), _cls.run(a))[1])
    return parser


def _plugin_commands(pm) -> list[type]:
    out: list[type] = []
    for impl in pm.hook.register_commands.get_hookimpls():
        name = pm.get_name(impl.plugin)
        try:
            out += list(impl.function() or [])
        except Exception as exc:
            raise PluginError(f"plugin {name!r} failed in register_commands(): {exc}") from exc
    return out


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    debug = "--debug" in argv
    logging.basicConfig(level=logging.DEBUG if debug else logging.WARNING, format="%(levelname)s %(name)s: %(message)s")
    try:
        from .plugins import get_plugin_manager

        pm = get_plugin_manager(entry_points="--no-entry-points" not in argv,
                                blocked=[argv[i + 1] for i, a in enumerate(argv[:-1]) if a == "--block"])
        parser = build_parser(_plugin_commands(pm))
        args = parser.parse_args(argv)
        if not getattr(args, "func", None):
            parser.print_help()
            return 0
        return int(args.func(args, pm) or 0)
    except KeyboardInterrupt:
        print("mocapflow: interrupted; finished steps are kept, run again to resume", file=sys.stderr)
        return 130
    except MocapflowError as exc:
        if debug:
            traceback.print_exc()
        print(f"mocapflow: error: {exc}", file=sys.stderr)
        return 2 if isinstance(exc, (ConfigError, PluginError)) else 1
    except Exception as exc:  # a bug: say so briefly, full traceback with --debug
        if debug:
            traceback.print_exc()
        else:
            print(f"mocapflow: internal error: {type(exc).__name__}: {exc} (run with --debug for the traceback)", file=sys.stderr)
        return 3


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
