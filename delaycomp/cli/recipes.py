"""``delaycomp run FILE.ssp`` again, from the recipe its first run left in the cache.

The first run of an archive whose FMUs are all native, stepped by the native core, in
which no FMU said anything, keeps its recipe (``delaycomp.orchestrator.replay``) with a
copy of what its FMUs need to run, in the build cache (``recipes/`` beside the FMUs),
under a key made of everything the run depends on: the archive's bytes (their digest),
every option of the command but those that only say where results go and how much is
said (``--out``, ``-q``/``-v``, ``--progress``), this platform, and delaycomp's own
sources (their sizes and times: an edited or reinstalled delaycomp records anew).

A later run of the same command (``--out`` may differ) replays it: the FMUs set up and
stepped as the first run did, from ctypes, without importing numpy, fmpy, lxml or the
loop's model, which is most of a short run's time. It writes the same CSV, bit for bit,
and says the same things, ``-v`` a line more. Where anything differs from the first run
(``delaycomp.orchestrator.replay.NotReplayed``: a file of the cache gone, a call that
does not return OK, a message an FMU logs), nothing of it is kept and the run goes the
whole way, which reports in its own words. ``--stepping python``, ``--plot``,
``--master`` other than ours, and a run with a progress bar on a terminal are never
replayed. The cache keeps the ``KEEP`` recipes used last.
"""

from __future__ import annotations

import hashlib
import json
import os
import sys
import time
from pathlib import Path

__all__ = ["KEEP", "remember", "replayed"]

#: recipes kept in the cache (the ones used last; a recipe holds a copy of its FMUs'
#: binaries, some hundred kB)
KEEP = 32
#: options that do not change what a run computes: where its results go, what it says,
#: the archive's path (its bytes are in the key)
_OUTPUT_ONLY = frozenset({"out", "verbosity", "progress", "scenario"})


def _folder() -> Path:
    from delaycomp.tmpfiles import cache_root

    return cache_root() / "recipes"


def _sources_stamp() -> list:
    """The size and time of every Python source of delaycomp (the package and, in a
    checkout, its ``orchestrator/``): a change to delaycomp is a new key."""
    import delaycomp
    import delaycomp.orchestrator

    roots = sorted({os.path.dirname(delaycomp.__file__),
                    *delaycomp.orchestrator.__path__})
    stamp = []
    stack = list(roots)
    while stack:
        folder = stack.pop()
        try:
            entries = list(os.scandir(folder))
        except OSError:
            continue
        for entry in entries:
            if entry.is_dir(follow_symlinks=False):
                if entry.name != "__pycache__":
                    stack.append(entry.path)
            elif entry.name.endswith(".py"):
                st = entry.stat()
                stamp.append((entry.path, st.st_size, st.st_mtime_ns))
    return sorted(stamp)


def _key(args) -> str | None:
    """The key of this command's recipe, ``None`` where it is never replayed."""
    if not (args.scenario.endswith(".ssp") and args.master == "delaycomp"
            and args.engine == "fmu" and args.stepping in ("auto", "native-core")
            and not args.plot and not args.compare):
        return None
    from delaycomp import progress
    from delaycomp.version import __version__

    if progress.shows(args.verbosity):  # a bar on a terminal: the whole run shows it
        return None
    sha = hashlib.sha256()
    try:
        with open(args.scenario, "rb") as fh:
            for chunk in iter(lambda: fh.read(1 << 20), b""):
                sha.update(chunk)
    except OSError:  # no such file: the whole run says so
        return None
    digest = sha.hexdigest()
    options = {k: v for k, v in sorted(vars(args).items()) if k not in _OUTPUT_ONLY}
    machine = os.uname().machine if hasattr(os, "uname") else os.environ.get(
        "PROCESSOR_ARCHITECTURE", "")
    text = json.dumps([__version__, sys.platform, machine, sys.implementation.cache_tag,
                       digest, options, _sources_stamp()], default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:24]


def replayed(args) -> int | None:
    """Run ``delaycomp run FILE.ssp`` from its recipe, as the first run did: the exit
    status, or ``None`` where there is no recipe or the replay gave way (nothing written
    then: the caller runs it whole)."""
    key = _key(args)
    if key is None:
        return None
    folder = _folder() / key
    try:
        stored = json.loads((folder / "recipe.json").read_text())
        recipe, shown = stored["recipe"], stored["shown"]
        recipe["folders"] = [str(folder / f) for f in recipe["folders"]]
    except (OSError, ValueError, KeyError, TypeError):
        return None
    from delaycomp.cli.execute import CORE_STEPPED, summary
    from delaycomp.formats.outputs import CsvStream, clear_previous
    from delaycomp.orchestrator.replay import NotReplayed, replay
    from delaycomp.progress import VERBOSE, info

    name = Path(args.scenario).name
    info(f"{name}: replayed from the recipe of its first run ({folder}), without numpy or "
         "fmpy", args.verbosity, VERBOSE)
    clear_previous(args.out)
    stream = CsvStream(args.out, recipe["names"]) if args.out else None
    started = time.perf_counter()
    try:
        done = replay(recipe, stream.write_flat if stream is not None else None)
    except NotReplayed as exc:
        if stream is not None:
            stream.discard()
        info(f"{name}: the replay gave way ({exc}): the whole run", args.verbosity, VERBOSE)
        return None
    except BaseException:
        if stream is not None:
            stream.finish(False)
        raise
    elapsed = time.perf_counter() - started
    for note in shown["notes"]:
        info(f"note: {note}", args.verbosity)
    info(f"{name}: {shown['estimate']}", args.verbosity, VERBOSE)
    info(f"{name}: {CORE_STEPPED}", args.verbosity, VERBOSE)
    if stream is not None:
        stream.finish(True)
    print(summary(name, done.rows, done.last_time, done.names, done.last_row, elapsed))
    try:
        os.utime(folder)  # used last: kept longest
    except OSError:
        pass
    return 0


def remember(args, result, shown: dict) -> None:
    """Keep ``result``'s recipe (``Result.recipe``) for a later run of the same command,
    with a copy of its FMUs' folders and what the command ``shown`` besides its rows and
    summary (``notes``, ``estimate``). Quietly nothing where it cannot be kept (a cache
    that cannot be written is not this run's failure)."""
    import shutil

    key = _key(args)
    if key is None or result.recipe is None:
        return
    root = _folder()
    target = root / key
    work = root / f".{key}.{os.getpid()}.part"
    recipe = dict(result.recipe)
    try:
        shutil.rmtree(work, ignore_errors=True)
        work.mkdir(parents=True)
        folders = []
        for i, source in enumerate(recipe["folders"]):
            shutil.copytree(source, work / f"fmu{i}")
            folders.append(f"fmu{i}")
        recipe["folders"] = folders
        (work / "recipe.json").write_text(json.dumps({"recipe": recipe, "shown": shown}))
        if target.exists():
            shutil.rmtree(target, ignore_errors=True)
        work.rename(target)
    except OSError:
        shutil.rmtree(work, ignore_errors=True)
        return
    _prune(root)
    from delaycomp.progress import VERBOSE, info

    info(f"{Path(args.scenario).name}: its recipe kept for the next run of this command "
         f"({target})", args.verbosity, VERBOSE)


def _prune(root: Path) -> None:
    """Keep the ``KEEP`` recipes used last."""
    import shutil

    try:
        kept = sorted((p for p in root.iterdir() if p.is_dir() and not p.name.startswith(".")),
                      key=lambda p: p.stat().st_mtime, reverse=True)
    except OSError:
        return
    for old in kept[KEEP:]:
        shutil.rmtree(old, ignore_errors=True)
