"""Temporary folders that a killed process does not leave behind, and atomic writes.

A folder made by ``temp_dir`` is named ``<prefix><pid>-<random>``; ``sweep``
removes the folders of a prefix whose process is gone (killed before its cleanup ran).
``build_lock`` lets one process build a cache entry while the others wait;
``zip_folder`` writes an archive (an FMU, an SSP) that appears whole or not at all.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
import zipfile
from collections.abc import Iterator
from pathlib import Path

try:  # POSIX; elsewhere the atomic rename alone keeps readers safe
    import fcntl
except ImportError:  # pragma: no cover - Windows
    fcntl = None  # type: ignore[assignment]  # no such module there: the locks are skipped


def cache_root() -> Path:
    """Where delaycomp keeps what it builds and records once for later runs:
    ``$DELAYCOMP_CACHE_DIR``, else ``$XDG_CACHE_HOME/delaycomp`` or ``~/.cache/delaycomp``."""
    root = os.environ.get("DELAYCOMP_CACHE_DIR") or os.path.join(
        os.environ.get("XDG_CACHE_HOME") or os.path.expanduser("~/.cache"), "delaycomp")
    return Path(root)


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:  # exists, owned by someone else
        return True
    return True


def sweep(prefix: str, folder: str | Path | None = None) -> int:
    """Remove ``<prefix><pid>-*`` folders of processes that no longer run; return how many.

    Parameters
    ----------
    prefix : str
        The prefix given to ``temp_dir``.
    folder : path, optional
        Where to look (default: the system's temporary folder).
    """
    root = Path(folder or tempfile.gettempdir())
    removed = 0
    try:
        entries = list(root.glob(f"{prefix}*"))
    except OSError:
        return 0
    for entry in entries:
        pid_text = entry.name[len(prefix):].split("-", 1)[0]
        if not pid_text.isdigit() or int(pid_text) == os.getpid() or _alive(int(pid_text)):
            continue
        if entry.is_dir() and not entry.is_symlink():
            shutil.rmtree(entry, ignore_errors=True)
            removed += 1
    return removed


@contextlib.contextmanager
def temp_dir(prefix: str) -> Iterator[str]:
    """A temporary folder ``<prefix><pid>-*``, removed on exit (stale ones swept first)."""
    sweep(prefix)
    with tempfile.TemporaryDirectory(prefix=f"{prefix}{os.getpid()}-") as tmp:
        yield tmp


def mkdtemp(prefix: str) -> str:
    """``tempfile.mkdtemp`` named ``<prefix><pid>-*`` (stale ones swept first)."""
    sweep(prefix)
    return tempfile.mkdtemp(prefix=f"{prefix}{os.getpid()}-")


@contextlib.contextmanager
def build_lock(target: Path) -> Iterator[None]:
    """Hold an exclusive lock named after ``target`` (``.<name>.lock`` beside it) while
    building it: concurrent first runs wait for the one that builds, then find the file."""
    if fcntl is None:  # pragma: no cover - Windows
        yield
        return
    lock = target.parent / f".{target.name}.lock"
    fd = os.open(lock, os.O_RDWR | os.O_CREAT | getattr(os, "O_NOFOLLOW", 0), 0o644)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)
        yield
    finally:
        fcntl.flock(fd, fcntl.LOCK_UN)
        os.close(fd)


def zip_folder(folder: Path, target: Path) -> Path:
    """Zip every file below ``folder`` (paths relative to it, sorted) into ``target``,
    written as a part file of this process beside it and renamed: a reader never sees half
    an archive, and two processes writing the same target (two runs building the same
    native FMU into the cache) never write into one part file."""
    part = target.with_name(f".{target.name}.{os.getpid()}.{os.urandom(4).hex()}.part")
    try:
        with zipfile.ZipFile(part, "w", zipfile.ZIP_DEFLATED) as zf:
            for path in sorted(folder.rglob("*")):
                if path.is_file():
                    zf.write(path, path.relative_to(folder).as_posix())
        part.replace(target)
    finally:
        part.unlink(missing_ok=True)
    return target


# -- outputs: written whole, never through a link ------------------------------------------

_NOFOLLOW = getattr(os, "O_NOFOLLOW", 0)  # POSIX: open() refuses a link in the last place


def new_file(path: Path, binary: bool = False):
    """Open ``path`` as a new, empty file for writing: whatever file or link was at that
    name is removed first (a link's target is never opened), the file is created with
    ``O_EXCL`` (and ``O_NOFOLLOW``), with the permissions the umask allows. Text mode
    writes UTF-8 with no newline translation (what ``csv`` needs)."""
    path = Path(path)
    if path.is_symlink() or path.is_file():
        path.unlink()
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL | _NOFOLLOW
                 | getattr(os, "O_BINARY", 0), 0o666)
    if binary:
        return os.fdopen(fd, "wb")
    return os.fdopen(fd, "w", newline="", encoding="utf-8")


def _part_name(path: Path) -> Path:
    """A working name beside ``path`` that no one else uses (this process, random)."""
    return path.with_name(f".{path.name}.{os.getpid()}.{os.urandom(4).hex()}.part"
                          f"{path.suffix}")


@contextlib.contextmanager
def replacing(path: str | Path, binary: bool = False) -> Iterator:
    """Write the file ``path`` as a whole: a new working file beside it (``new_file``)
    that is renamed over ``path`` when the block ends without error, and removed
    otherwise. A link at ``path`` is replaced by the file, its target left alone; a reader
    never sees half a file.

    Examples
    --------
    >>> import tempfile
    >>> folder = Path(tempfile.mkdtemp())
    >>> (folder / "target.txt").write_text("keep")
    4
    >>> (folder / "out.txt").symlink_to(folder / "target.txt")
    >>> with replacing(folder / "out.txt") as fh:
    ...     _ = fh.write("new")
    >>> (folder / "out.txt").read_text(), (folder / "out.txt").is_symlink()
    ('new', False)
    >>> (folder / "target.txt").read_text()
    'keep'
    """
    path = Path(path)
    with replacing_path(path) as part:
        with new_file(part, binary) as fh:
            yield fh


@contextlib.contextmanager
def replacing_path(path: str | Path) -> Iterator[Path]:
    """A working path beside ``path`` (same suffix, for writers that go by it: a plot, a
    zip) for the block to write; renamed over ``path`` when the block ends without error,
    removed otherwise (see ``replacing``)."""
    path = Path(path)
    part = _part_name(path)
    try:
        yield part
        os.replace(part, path)
    finally:
        with contextlib.suppress(OSError):
            part.unlink()


def write_text(path: str | Path, text: str) -> Path:
    """Write ``text`` (UTF-8, newlines as given) to ``path`` through ``replacing``."""
    with replacing(path) as fh:
        fh.write(text)
    return Path(path)
