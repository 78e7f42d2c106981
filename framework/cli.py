"""The ``mocapflow`` command line: run, plan, plugins, sql, plus plugin commands.

Errors a user can fix are printed as one line (exit 2 for configuration problems, 1 for
failures while running); ``--debug`` shows tracebacks.

Start-up is lazy: this module imports only the standard library, :mod:`.errors` and
pluggy. A built-in command loads the plugins only when it needs the registries (``sql``
never does); ``--help`` and plugin commands load only the plugins that provide commands
(built-ins are found by reading their source, see :func:`command_plugin_modules`), so
listing the commands imports neither NumPy's nor pydantic's world unless those plugins do.
"""

from __future__ import annotations

import argparse
import logging
import sys
import traceback
import typing
from functools import partial
from pathlib import Path
from typing import TYPE_CHECKING, Any

import pluggy

from .errors import ConfigError, MocapflowError, PluginError

if TYPE_CHECKING:
    from .runner import StepReport

BUILTIN_COMMANDS = ("run", "plan", "plugins", "sql")
# built-in commands that need the plugin manager (the registries); `sql` reads Parquet only
_COMMANDS_WITH_PLUGINS = ("run", "plan", "plugins")


def _echo(msg: str) -> None:
    print(msg, flush=True)


def _err(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


def _warn(msg: str) -> None:
    print(f"mocapflow: warning: {msg}", file=sys.stderr, flush=True)


def _rejects_warnings(reports: list[StepReport]) -> list[str]:
    """One line per computed step that rejected input files (their summary says so)."""
    lines = []
    for r in reports:
        n = (r.summary or {}).get("rejects")
        if isinstance(n, int) and not isinstance(n, bool) and n > 0:
            files = r.summary.get("files")
            what = f"{n} of {files} files" if isinstance(files, int) else f"{n} file{'s' * (n != 1)}"
            lines.append(
                f"{r.step_id}: {what} rejected: see the rejects view "
                f'(mocapflow sql WORKSPACE "SELECT * FROM {r.step_id.replace("-", "_")}_rejects")'
            )
        w = (r.summary or {}).get("warnings")
        if isinstance(w, int) and not isinstance(w, bool) and w > 0:
            lines.append(
                f"{r.step_id}: {w} repair{'s' * (w != 1)} of files read (a header the data contradict): see "
                f'mocapflow sql WORKSPACE "SELECT * FROM {r.step_id.replace("-", "_")}_warnings"'
            )
    return lines


def _needed(pm: pluggy.PluginManager | None) -> pluggy.PluginManager:
    if pm is None:  # pragma: no cover - main() builds one for every command that needs it
        raise PluginError("this command needs the plugin manager")
    return pm


def cmd_run(args: argparse.Namespace, pm: pluggy.PluginManager | None) -> int:
    from .runner import run_pipeline

    _echo(f"mocapflow: running {args.pipeline}")
    reports = run_pipeline(
        args.pipeline,
        workspace=args.workspace,
        overrides=args.set,
        jobs=args.jobs,
        force=args.force,
        pm=pm,
        echo=_echo,
        wait=args.wait,
    )
    for line in _rejects_warnings(reports):
        _warn(line)
    computed = sum(r.status == "computed" for r in reports)
    fresh = len(reports) - computed
    if computed == 0:
        _echo(f"nothing to do: all {fresh} steps up to date")
    else:
        _echo(f"done: {computed} computed, {fresh} up to date")
    return 0


def cmd_plan(args: argparse.Namespace, pm: pluggy.PluginManager | None) -> int:
    from .plugins import build_registries
    from .runner import default_workspace, plan_pipeline
    from .workspace import Workspace

    plan = plan_pipeline(args.pipeline, args.set, registries=build_registries(_needed(pm)))
    ws = Workspace(Path(args.workspace).resolve() if args.workspace else default_workspace(plan))
    fps = plan.fingerprints()
    _echo(f"pipeline {plan.source.config.name!r}: {len(plan.steps)} steps, workspace {ws.path}")
    for s in plan.steps:
        found = ws.fingerprint(s.step_id)
        state = "would compute" if found is None else "up to date" if found == fps[s.step_id] else "would recompute"
        ins = ", ".join(f"{k}<-{v}" for k, v in s.inputs.items()) or "-"
        _echo(f"  {s.step_id:<16} {s.key:<28} inputs: {ins:<30} [{state}]")
        for k, v in s.component.get_params().items():
            _echo(f"      {k} = {v!r}")
    _echo("plan is valid")
    return 0


def format_annotation(ann: object) -> str:
    """A parameter's type as a user reads it: ``'record' | 'fail'`` for a Literal (its
    choices), ``int | None`` for a Union, ``list[float]``, ``dict[str, int]``, a class name."""
    origin, args = typing.get_origin(ann), typing.get_args(ann)
    if origin is typing.Literal:
        return " | ".join(repr(a) for a in args)
    if ann is type(None):
        return "None"
    if origin is typing.Union or type(ann).__name__ == "UnionType":
        return " | ".join(format_annotation(a) for a in args)
    if origin is typing.Annotated:
        return format_annotation(args[0])
    if origin is not None and args:
        name = getattr(origin, "__name__", None) or str(origin).replace("typing.", "")
        return f"{name}[{', '.join('...' if a is Ellipsis else format_annotation(a) for a in args)}]"
    if isinstance(ann, type):
        return ann.__name__
    return str(ann).replace("typing.", "")


def _param_rows(cls: type[Any]) -> list[str]:
    rows = []
    for name, field in cls.Params.model_fields.items():
        default = "required" if field.is_required() else f"default {field.get_default(call_default_factory=True)!r}"
        desc = f" - {field.description}" if field.description else ""
        rows.append(f"        {name}: {format_annotation(field.annotation)} ({default}){desc}")
    return rows


def cmd_plugins(args: argparse.Namespace, pm: pluggy.PluginManager | None) -> int:
    from .plugins import build_registries
    from .registry import KINDS

    regs = build_registries(_needed(pm))
    if args.count_params:
        return _count_params(regs)
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


def _count_params(regs: Any) -> int:
    """``mocapflow plugins --count-params``: the parameters each component declares (nested
    parameter models counted by their fields) and the total (docs: at most 150)."""
    from pydantic import BaseModel

    from .params import count_parameters
    from .registry import KINDS

    total, comps = 0, 0
    for kind in KINDS:
        for name, cls in regs[kind]:
            params = getattr(cls, "Params", None)
            if not (isinstance(params, type) and issubclass(params, BaseModel)):
                continue
            n = count_parameters(params)
            if n:
                comps, total = comps + 1, total + n
                _echo(f"{kind}.{name:<28} {n:4d}")
    _echo(f"{comps} components declare {total} parameters")
    return 0


def cmd_sql(args: argparse.Namespace, pm: pluggy.PluginManager | None) -> int:
    if not Path(args.workspace).exists():  # the common typo, answered before pyarrow and duckdb load
        raise ConfigError(f"workspace {args.workspace} does not exist (run a pipeline first)")
    from .catalog import Catalog, format_table, limited_query
    from .output_paths import refuse_dataset_path
    from .workspace import export_table

    if args.output:  # refuse what cannot be written before the work
        out = Path(args.output)
        refuse_dataset_path(out, "--output", workspaces=[args.workspace])
        if out.is_dir():
            raise ConfigError(f"--output {out} is a directory: give a file name (e.g. {out / 'result.csv'})")
        if args.format == "table" and out.suffix.lower() not in (".csv", ".json", ".parquet", ""):
            raise ConfigError(
                f"--output {out}: unknown format {out.suffix!r}; use .csv, .json or .parquet, or --format"
            )
    if not args.query:
        with Catalog(args.workspace) as cat:
            _echo("views: " + ", ".join(sorted(cat.views)))
        return 0
    # in a child process whose address space is capped and which is killed past --timeout
    table = limited_query(
        args.workspace, args.query, args.param or None, timeout=args.timeout or None, memory_limit=args.memory_limit
    )
    if args.output:
        fmt = args.format if args.format != "table" else Path(args.output).suffix.lstrip(".").lower() or "csv"
        Path(args.output).parent.mkdir(parents=True, exist_ok=True)  # a new folder is made, as a user expects
        export_table(table, args.output, fmt)
        _echo(f"wrote {table.num_rows} rows to {args.output}")
    elif args.format == "csv":
        import io

        import pyarrow.csv as pacsv

        from .workspace import csv_options, flat_table

        buf = io.BytesIO()
        pacsv.write_csv(flat_table(table), buf, csv_options())  # list and struct columns as JSON text
        sys.stdout.write(buf.getvalue().decode())
    elif args.format == "json":
        from .workspace import write_json

        write_json(table, sys.stdout)
    elif args.format == "parquet":
        raise ConfigError("--format parquet needs --output FILE")
    else:
        _echo(format_table(table, max_rows=args.max_rows))
    return 0


def build_parser(plugin_commands: list[type[Any]]) -> argparse.ArgumentParser:
    from mocapflow import __version__

    from .options import SQL_MEMORY_LIMIT, SQL_TIMEOUT_S, float_at_least, int_at_least

    parser = argparse.ArgumentParser(prog="mocapflow", description="Searchable, clean motion-capture databases.")
    parser.add_argument("--version", action="version", version=f"mocapflow {__version__}")
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
    p.add_argument(
        "--jobs", "-j", type=int_at_least(0), default=None, help="worker processes for per-clip work (0 = all cores)"
    )
    p.add_argument("--force", action="store_true", help="recompute every step")
    p.add_argument(
        "--wait",
        type=float_at_least(0, infinite=True),
        default=0.0,
        metavar="SECONDS",
        help="wait this long for another run holding the workspace (default: refuse at once)",
    )
    p.set_defaults(func=cmd_run)

    p = sub.add_parser("plan", help="validate a pipeline and show what would run")
    common(p)
    p.set_defaults(func=cmd_plan)

    p = sub.add_parser("plugins", help="list plugins, their components and parameters")
    p.add_argument(
        "--count-params",
        action="store_true",
        help="count the parameters of each component (nested models by their fields) and in all",
    )
    p.set_defaults(func=cmd_plugins)

    p = sub.add_parser("sql", help="query a workspace with DuckDB (one view per dataset, plus clips)")
    p.add_argument("workspace")
    p.add_argument("query", nargs="?", help="SELECT ... (omit to list the views)")
    p.add_argument("--param", action="append", default=[], help="value for a ? placeholder (repeatable)")
    p.add_argument(
        "--format",
        choices=("table", "csv", "json", "parquet"),
        default="table",
        help="csv: list and struct columns as JSON text; json: an array of row objects",
    )
    p.add_argument("--output", "-o", help="write the result to this file (csv, json or parquet)")
    p.add_argument("--max-rows", type=int_at_least(0), default=50)
    p.add_argument(
        "--timeout",
        type=float_at_least(0),
        default=SQL_TIMEOUT_S,
        metavar="SECONDS",
        help=f"stop a query running longer (default {SQL_TIMEOUT_S:g}; 0: no limit)",
    )
    p.add_argument(
        "--memory-limit",
        default=SQL_MEMORY_LIMIT,
        metavar="SIZE",
        help=f"memory a query and its result may take (default {SQL_MEMORY_LIMIT})",
    )
    p.set_defaults(func=cmd_sql)

    for cls in plugin_commands:
        if cls.name in BUILTIN_COMMANDS:
            raise PluginError(f"plugin command {cls.name!r} ({cls.__module__}) clashes with a built-in command")
        p = sub.add_parser(cls.name, help=getattr(cls, "help", ""))
        cls.add_arguments(p)
        # the command runs with the context built in main() (--block, --no-entry-points): run(args, ctx)
        p.set_defaults(func=partial(_run_plugin_command, cls), command_cls=cls)
    return parser


def _run_plugin_command(cls: type[Any], args: argparse.Namespace, pm: pluggy.PluginManager | None) -> int:
    from .commands import context_of, run_command

    return run_command(cls, args, context_of(args))


def _plugin_commands(pm: pluggy.PluginManager) -> list[type[Any]]:
    from .plugins import plugin_commands

    return plugin_commands(pm)  # a plugin whose hook raises is reported and skipped


def _global_options(argv: list[str]) -> tuple[str | None, bool, list[str]]:
    """``(command, load entry points, blocked plugins)`` read before the parser exists (it
    depends on the plugins): the first word that is not an option or the value of
    ``--block``."""
    command, blocked, i = None, [], 0
    while i < len(argv):
        a = argv[i]
        if a == "--block" and i + 1 < len(argv):
            blocked.append(argv[i + 1])
            i += 2
            continue
        if a.startswith("--block="):
            blocked.append(a.split("=", 1)[1])
        elif command is None and not a.startswith("-"):
            command = a
            break
        i += 1
    return command, "--no-entry-points" not in argv[: i if command else len(argv)], blocked


def _check_blocked(blocked: list[str]) -> None:
    """:class:`ConfigError` for a name given to ``--block`` that names no built-in plugin
    module and no entry point (a typo would otherwise block nothing, silently)."""
    if not blocked:
        return
    from importlib import metadata

    from .plugins import ENTRY_POINT_GROUP, builtin_plugin_modules
    from .registry import did_you_mean

    known = [*builtin_plugin_modules(), *(ep.name for ep in metadata.entry_points(group=ENTRY_POINT_GROUP))]
    for name in dict.fromkeys(blocked):
        if name not in known:
            raise ConfigError(
                f"--block {name}: no plugin of that name{did_you_mean(name, known)}; plugins: " + ", ".join(known)
            )


def _plugin_manager(command: str | None, entry_points: bool, blocked: list[str]) -> pluggy.PluginManager | None:
    """All plugins for run/plan/plugins, none for sql (``None``)."""
    from .plugins import get_plugin_manager

    if command in _COMMANDS_WITH_PLUGINS:
        return get_plugin_manager(entry_points=entry_points, blocked=blocked)
    return None


def _exit_without_a_last_collection() -> None:
    """At exit: the interpreter's last garbage collection walked every object of a run (0.2 s
    of a 2.5 s ingest, docs/scale-out.md); outputs and the lock are closed before."""
    import gc

    gc.freeze()


def main(argv: list[str] | None = None) -> int:
    if argv is None:  # the console script: this process ends with the command
        import atexit

        # a caller's own process (main(argv) from Python, the tests) keeps its exit as it was
        atexit.unregister(_exit_without_a_last_collection)  # once, however often main() runs
        atexit.register(_exit_without_a_last_collection)  # first registered, so it runs last
        argv = sys.argv[1:]
    debug = "--debug" in argv
    logging.basicConfig(level=logging.DEBUG if debug else logging.WARNING, format="%(levelname)s %(name)s: %(message)s")
    try:
        command, entry_points, blocked = _global_options(argv)
        _check_blocked(blocked)
        if command in BUILTIN_COMMANDS or (command is None and "--version" in argv):
            parser = build_parser([])  # the parser of a built-in needs no plugin (`run --help` is quick)
            args = parser.parse_args(argv)
            if command == "run":  # before the plugins import NumPy: BLAS sized for the workers as it loads
                from .threads import size_blas_for_workers, workers_on_this_host

                size_blas_for_workers(workers_on_this_host(args.pipeline, args.jobs))
            pm = _plugin_manager(command, entry_points, blocked)
        else:
            # one context for the plugin commands (every built-in plugin module is light to
            # import; the registries are built when a command asks for them)
            from .commands import CommandContext

            ctx = CommandContext.from_switches(entry_points=entry_points, blocked=blocked)
            pm = ctx.plugin_manager
            parser = build_parser(_plugin_commands(pm))
            args = parser.parse_args(argv)
            args.command_context = ctx
        if not getattr(args, "func", None):
            parser.print_help()
            return 0
        from .progress import announce_compilation

        # `run` reports progress on stdout; other commands keep stdout for their results
        with announce_compilation(_echo if args.command == "run" else _err):
            return int(args.func(args, pm) or 0)
    except KeyboardInterrupt:
        print("mocapflow: interrupted; finished steps are kept, run again to resume", file=sys.stderr)
        return 130
    except BrokenPipeError:  # `mocapflow sql ... | head`: the reader has what it wanted
        import os

        # Python flushes stdout again at exit: point it at /dev/null so that does not fail too
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 141  # 128 + SIGPIPE, what a shell tool killed by the closed pipe returns
    except MocapflowError as exc:
        if debug:
            traceback.print_exc()
        print(f"mocapflow: error: {exc}", file=sys.stderr)
        return 2 if isinstance(exc, (ConfigError, PluginError)) else 1
    except OSError as exc:  # a path the user gave that the system refuses (too long, not a folder...)
        if exc.filename is None:
            return _internal_error(exc, debug)
        if debug:
            traceback.print_exc()
        name = str(exc.filename)
        print(
            f"mocapflow: error: {name[:120]}{'...' if len(name) > 120 else ''}: {exc.strerror or exc}", file=sys.stderr
        )
        return 1
    except Exception as exc:  # a bug: say so briefly, full traceback with --debug
        return _internal_error(exc, debug)


def _internal_error(exc: BaseException, debug: bool) -> int:
    """A bug: said briefly (exit 3), the full traceback with ``--debug``."""
    if debug:
        traceback.print_exc()
    else:
        print(
            f"mocapflow: internal error: {type(exc).__name__}: {exc} (run with --debug for the traceback)",
            file=sys.stderr,
        )
    return 3


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
