"""Output paths checked by identity: a path a command other than the runner writes is
refused when it is, or leads to (hard links, symbolic links anywhere on the path, links inside
an output folder), a file or folder a workspace owns (:func:`refuse_dataset_path`)."""

from __future__ import annotations

import contextlib
import errno
import os
from collections.abc import Callable
from pathlib import Path

from .errors import ConfigError
from .workspace import MANIFEST, MARKER, RUNNER_DIR, _refuse_name

#: How many entries of an existing output folder :func:`refuse_dataset_path` inspects before it
#: refuses the folder as too large to check (choose an empty or new folder instead).
OUTPUT_DIR_CHECK_LIMIT = 100_000


def _workspace_of(path: Path) -> Path | None:
    """The workspace folder ``path`` is (or lies in), found by its step folders' manifests or
    the runner's marked folder; None if none of its ancestors is one."""
    for cand in (path, *path.parents):
        if (cand / MANIFEST).is_file():
            return cand.parent
        if (cand / RUNNER_DIR / MARKER).is_file():
            return cand
    return None


def workspace_identities(workspace: str | Path) -> dict[tuple[int, int], Path]:
    """``(st_dev, st_ino)`` of every file and folder a run owns in ``workspace`` (its step
    folders holding a :data:`MANIFEST`, everything inside them, and the runner's folder), each
    mapped to its path: another name of one of them (a hard link, a bind mount) is the same
    object. Symbolic links inside are not followed."""
    ws = Path(workspace)
    owned: dict[tuple[int, int], Path] = {}
    roots: list[Path] = []
    with contextlib.suppress(OSError):
        for d in ws.iterdir():
            if d.name == RUNNER_DIR or (not d.is_symlink() and d.is_dir() and (d / MANIFEST).is_file()):
                roots.append(d)
    for root in roots:
        if root.is_symlink():
            continue
        for top, dirs, files in os.walk(root, followlinks=False):
            for name in (".", *dirs, *files):
                q = Path(top) / name if name != "." else Path(top)
                with contextlib.suppress(OSError):
                    st = q.lstat()
                    owned[(st.st_dev, st.st_ino)] = q
    return owned


def _check_folder(
    real: Path,
    path: str | Path,
    option: str,
    found: set[Path | None],
    owned: dict[tuple[int, int], Path],
    check: Callable[[Path, str | Path], None],
) -> None:
    """Every entry already in the output folder ``real``, links followed (each folder once)."""
    stack, visited, seen = [real], set(), 0
    while stack:
        folder = stack.pop()
        try:
            st = folder.stat()
            entries = list(os.scandir(folder))
        except OSError:
            continue
        if (st.st_dev, st.st_ino) in visited:
            continue
        visited.add((st.st_dev, st.st_ino))
        for entry in entries:
            seen += 1
            if seen > OUTPUT_DIR_CHECK_LIMIT:
                raise ConfigError(
                    f"{option} {path}: more than {OUTPUT_DIR_CHECK_LIMIT} entries to check for links "
                    "into a workspace: choose an empty or new folder"
                )
            q = Path(entry.path)
            target = q.resolve() if entry.is_symlink() else q
            if target != q:
                _refuse_name(target, q, option)
                inner = _workspace_of(target)
                if inner not in found:
                    found.add(inner)
                    if inner is not None:
                        owned.update(workspace_identities(inner))
            check(target, q)
            if target.is_dir():
                stack.append(target)


def _refuse_kind(real: Path, p: Path, path: str | Path, option: str, directory: bool) -> None:
    """A file output names no folder and no device, pipe or socket; a folder output no file."""
    if not directory and (real.is_dir() or real == real.parent):
        raise ConfigError(f"{option} {path}: {real} is a directory: give a file name (e.g. {p / 'result'})")
    if directory and real.exists() and not real.is_dir():
        raise ConfigError(f"{option} {path}: {real} exists and is not a folder: give a folder name")
    if not directory and real.exists() and not real.is_file():  # a device, a pipe: renaming over it replaces it
        raise ConfigError(
            f"{option} {path}: {real} is not a regular file (a device, a pipe or a socket): give a file name"
        )


def refuse_dataset_path(
    path: str | Path,
    option: str,
    *,
    workspaces: tuple[str | Path, ...] | list[str | Path] = (),
    directory: bool = False,
) -> Path:
    """``path`` (made absolute) if a command other than the runner may write it; a
    :class:`ConfigError` naming ``option`` when it is, or leads to, a file or folder of a
    workspace's datasets (a folder holding a :data:`MANIFEST`, or inside one) or of the
    runner's own folder: only ``mocapflow run`` writes there, or the next run would take a
    foreign file for its output. Checked by identity, not only by name, before any work:

    - every symbolic link on the path is resolved (the resolved path is checked too);
    - a folder on the path that *is* a workspace folder under another name (a bind mount) is
      refused: ``(st_dev, st_ino)`` are compared with those of ``workspaces`` (the command's
      own workspace) and of any workspace found above the path;
    - an existing target file with more than one hard link is refused: it may be another name
      of a dataset file (named when it is one of ``workspaces``');
    - ``directory=True`` (the command writes files *into* ``path``): every entry already in
      the folder is checked the same way (a link inside it into a step folder is refused).
    """
    if not str(path).strip() or "\x00" in str(path):
        raise ConfigError(f"{option} {str(path)[:40]!r}: expected a file or folder name")
    p = Path(path).expanduser().absolute()
    try:
        real = p.resolve()
        longest = max((len(os.fsencode(part)) for part in real.parts), default=0)
        if longest > 255:  # the usual file name limit: refused before any work, not when written
            raise OSError(errno.ENAMETOOLONG, os.strerror(errno.ENAMETOOLONG))
    except (OSError, RuntimeError) as exc:  # a name too long, a loop of links
        raise ConfigError(
            f"{option} {str(path)[:80]}: cannot be written ({getattr(exc, 'strerror', None) or exc})"
        ) from None
    _refuse_kind(real, p, path, option, directory)
    for q in dict.fromkeys((p, real)):
        _refuse_name(q, path, option)
    found: set[Path | None] = {_workspace_of(q) for q in (p, real)}
    owned: dict[tuple[int, int], Path] = {}
    for ws in dict.fromkeys([*(Path(w) for w in workspaces), *(w for w in found if w is not None)]):
        owned.update(workspace_identities(ws))

    def check(q: Path, shown: str | Path) -> None:
        try:
            st = q.stat()
        except OSError:
            return  # not there (yet): nothing to alias
        hit = owned.get((st.st_dev, st.st_ino))
        if hit is not None:
            raise ConfigError(
                f"{option} {shown}: {q} is {hit} of a mocapflow workspace under another name "
                "(a hard link or mount); only `mocapflow run` writes there: choose another path"
            )
        if q.is_file() and st.st_nlink > 1:
            raise ConfigError(
                f"{option} {shown}: {q} has {st.st_nlink} hard links (it may be another name of a dataset "
                "file, which writing would change): remove it or choose another path"
            )

    for anc in (real, *real.parents):
        if anc == anc.parent:
            break
        check(anc, path)
    if directory and real.is_dir():
        _check_folder(real, path, option, found, owned, check)
    return p
