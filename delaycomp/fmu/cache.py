"""The build cache of the Python FMUs: where an FMU of a kind and configuration lives
(``fmu_path``, ``source_fmu``), built there on first use, and the checks that refuse
a file that is not the FMU it should be (``check_fmu``).

The cache is ``$DELAYCOMP_CACHE_DIR`` or ``~/.cache/delaycomp``, one folder per digest of
everything that goes into an FMU.
"""

from __future__ import annotations

import json
import os
import stat
import zipfile
from pathlib import Path

from delaycomp.errors import BadFileError
from delaycomp.fmu.build import (
    CONFIG_NAME,
    DEFAULT_CONFIG,
    FMUS,
    build_fmu,
    model_identifier,
    source_digest,
)
from delaycomp.system import FmuFile, Source
from delaycomp.tmpfiles import build_lock
from delaycomp.version import __version__

__all__ = ["cache_hit", "check_fmu", "check_sources", "default_fmu_dir", "fmu_file_name",
           "fmu_path", "source_digest", "source_fmu"]


def default_fmu_dir() -> Path:
    """Build cache: ``$DELAYCOMP_CACHE_DIR`` or ``~/.cache/delaycomp``, per source digest."""
    from delaycomp.tmpfiles import cache_root

    return cache_root() / f"fmus-{__version__}-{source_digest()}"


def fmu_file_name(kind: str, config: dict) -> str:
    """``<ModelIdentifier>.fmu`` for the default dimensions, else with the config in it."""
    ident = model_identifier(kind, config)
    if FMUS[kind].template or config == DEFAULT_CONFIG[kind]:
        return f"{ident}.fmu"
    tag = "_".join(f"{k}{config[k]}" for k in sorted(config))
    return f"{ident}_{tag}.fmu"


def fmu_path(kind: str, config: dict, fmu_dir: Path | None = None) -> Path:
    """Path of the FMU for ``kind`` and ``config`` in ``fmu_dir``; built there if missing.

    An FMU already there is checked first (``check_fmu``): a corrupt or foreign file
    raises ``BadFileError`` before anything runs; in a ``fmu_dir`` of the caller's also
    one built from other sources (the cache's folders are named by their digest).
    """
    own = fmu_dir is not None
    fmu_dir = Path(fmu_dir) if fmu_dir is not None else default_fmu_dir()
    if fmu_dir.exists() and not fmu_dir.is_dir():
        raise BadFileError(fmu_dir, "is not a folder (--fmu-dir wants a folder of FMUs)")
    path = fmu_dir / fmu_file_name(kind, config)
    _regular_or_missing(path)
    built = False
    if not path.exists():
        fmu_dir.mkdir(parents=True, exist_ok=True)
        with build_lock(path):  # parallel first runs: one builds, the others wait
            if not path.exists():
                build_fmu(kind, fmu_dir, config, path.name)
                built = True
    check_fmu(path, kind, config, sources=own)
    cache_hit(path, model_identifier(kind, config), built)
    return path


#: the FMU files whose cache hit this process told (``cache_hit``)
_HITS: set[str] = set()


def cache_hit(path: Path, ident: str, built: bool = False) -> None:
    """Under ``-v`` (``delaycomp.progress.detail``), one line for the FMU ``ident``
    found in the cache at ``path``, ``cache hit: <ident> (<path>)``, once per file and
    process (the runs of a sweep look up the same FMUs); ``built``: this process has just
    built it (its build said so), no line."""
    from delaycomp.progress import detail

    key = str(path)
    if key in _HITS:
        return
    _HITS.add(key)
    if not built:
        detail(f"cache hit: {ident} ({path})")


def _regular_or_missing(path: Path) -> None:
    """Refuse a link, a FIFO, a device or a folder where an FMU file belongs: reading one
    could hang (a FIFO) or never end (``/dev/zero``), and building through a link would
    write outside the folder."""
    try:
        mode = os.lstat(path).st_mode
    except FileNotFoundError:
        return
    except OSError as exc:
        raise BadFileError(path, f"cannot be read: {exc.strerror}") from None
    if stat.S_ISLNK(mode):
        raise BadFileError(path, "is a symbolic link: FMUs in --fmu-dir must be regular "
                                 "files (copy the file there)")
    if not stat.S_ISREG(mode):
        raise BadFileError(path, "is not a regular file: FMUs in --fmu-dir must be regular "
                                 "files")


#: FMU files already checked in this process, with their modification time and size
_CHECKED: set[tuple] = set()


def check_fmu(path: Path, kind: str, config: dict, sources: bool = False) -> None:
    """Refuse an FMU that is not a zip, has no readable modelDescription, is of another
    model, or was built for other dimensions or another delaycomp version; with
    ``sources`` (an FMU of a folder the user named, ``--fmu-dir``: the cache's folders are
    named by the digest) also one built from other sources than this delaycomp's (the
    ``sources`` digest its build configuration records: ``source_digest``, or
    ``delaycomp.fmu.native.sources_digest`` for a native one). A file checked before and
    unchanged since is not read again (runs of a sweep look up the same FMUs)."""
    try:
        st = Path(path).stat()
        key = (str(path), st.st_mtime_ns, st.st_size, kind,
               json.dumps(config, sort_keys=True, default=str), sources)
    except OSError:
        key = None
    if key is not None and key in _CHECKED:
        return
    _regular_or_missing(Path(path))
    _check_fmu(path, kind, config, sources)
    if key is not None:
        _CHECKED.add(key)


def _rebuild_hint(path: Path) -> str:
    """What to do about a stale FMU of ``--fmu-dir`` DIR: DIR rebuilt, or the file gone (a
    run builds a missing FMU)."""
    return (f"rebuild the folder: delaycomp build --out {Path(path).parent}, or delete the "
            "file")


def _check_fmu(path: Path, kind: str, config: dict, sources: bool = False) -> None:
    from fmpy import read_model_description

    ident = model_identifier(kind, config)
    try:
        with zipfile.ZipFile(path) as zf:
            names = set(zf.namelist())
            if "modelDescription.xml" not in names:
                raise BadFileError(path, "is not an FMU: it has no modelDescription.xml")
            built = zf.read(f"resources/{CONFIG_NAME}") if (
                f"resources/{CONFIG_NAME}" in names) else None
        md = read_model_description(str(path), validate=False)
    except BadFileError:
        raise
    except zipfile.BadZipFile:
        raise BadFileError(path, "is not an FMU: not a zip archive") from None
    except Exception as exc:  # noqa: BLE001 - any parse failure is a bad file
        raise BadFileError(path, f"is not a readable FMU: {type(exc).__name__}: {exc}"
                           ) from None
    found = md.coSimulation.modelIdentifier if md.coSimulation else None
    if found != ident:
        what = f"model {found!r}" if found else "a model without co-simulation"
        raise BadFileError(path, f"is an FMU of {what}, expected {ident!r} (delete it or use "
                                 "another --fmu-dir to rebuild)")
    if built is None:
        raise BadFileError(path, f"is not a delaycomp FMU: no resources/{CONFIG_NAME}")
    try:
        cfg = json.loads(built)
    except ValueError:
        raise BadFileError(path, f"has a corrupt resources/{CONFIG_NAME}") from None
    if cfg.get("version") != __version__:
        raise BadFileError(path, f"was built by delaycomp {cfg.get('version')!r}, this is "
                                 f"{__version__!r} ("
                                 + (_rebuild_hint(path) if sources else "delete it to rebuild")
                                 + ")")
    if sources and not cfg.get("native"):
        # a native FMU's sources are checked by delaycomp.fmu.native, whose digest it is
        check_sources(path, cfg, source_digest())
    wanted = {k: v for k, v in config.items() if k != "model"}
    differs = {k: cfg.get(k) for k, v in wanted.items() if cfg.get(k) != v}
    if differs:
        raise BadFileError(path, f"was built for {differs}, this loop needs "
                                 f"{ {k: wanted[k] for k in differs} }")


def check_sources(path: Path, built: dict, digest: str) -> None:
    """Refuse the FMU ``path`` (``BadFileError``, one line saying how to rebuild) whose
    build configuration ``built`` records other sources than ``digest``: stale."""
    if built.get("sources") != digest:
        raise BadFileError(path, f"is stale: it was built from other sources than this "
                                 f"delaycomp {__version__}'s "
                                 f"({_rebuild_hint(path)})")


def source_fmu(source: Source, fmu_dir: Path | None = None) -> Path:
    """The FMU file of an instance's source: a given file as it is, else the built FMU of
    its kind and configuration (``fmu_path``)."""
    if isinstance(source, FmuFile):
        return Path(source.path)
    return fmu_path(*source.build_key(), fmu_dir)
