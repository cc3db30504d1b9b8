"""A loop's native FMUs: whether each instance has a native twin (``check_native``), the
twins' files to run it with (``native_fmus``: from a folder ``delaycomp build --out`` wrote,
``fmus_in_dir``, else from the native build cache), and the commands' default, native
where it can be had and the Python FMUs with the reason otherwise (``native_or_why``).
"""

from __future__ import annotations

import os
from pathlib import Path

from delaycomp.fmu import toolchain
from delaycomp.fmu.build import model_identifier
from delaycomp.fmu.native import (
    MODEL_KINDS,
    NATIVE_KINDS,
    built_config,
    clocked_config,
    native_fmu_path,
    native_twin,
    sources_digest,
)
from delaycomp.fmu.toolchain import NativeBuildError

__all__ = ["check_native", "choose", "fmus_in_dir", "native_fmus", "native_or_why",
           "why_not_native"]


def fmus_in_dir(loop, fmu_dir: Path, fmus: str = "auto", fmi: int = 2,
                clocked: bool = False) -> tuple[str | None, dict[str, Path]]:
    """What ``delaycomp build --out fmu_dir`` (or an earlier run) left in ``fmu_dir`` for
    ``loop``: the kind of the FMUs there under their own names (``fmu_file_name``: the
    names ``build --out`` writes), ``"native"`` or ``"python"`` (``None``: none there),
    and those files by instance.

    Each file is checked (``check_fmu``: a delaycomp FMU of the instance's model and
    dimensions, built by this delaycomp from these sources), then against the FMUs the
    run asks for: ``fmus`` (``auto``: the kind of the first file there; ``native``;
    ``python``) and ``fmi`` (3: native FMI 3.0 ones; ``clocked``: the controller's clocked
    variant).

    Raises
    ------
    delaycomp.errors.BadFileError
        A file there is stale or of the wrong kind: one line naming it and what to do.
    """
    from delaycomp.errors import BadFileError
    from delaycomp.fmu.cache import cache_hit, check_fmu, check_sources, fmu_file_name
    from delaycomp.system.loop import FmuFile

    fmu_dir = Path(fmu_dir)
    kind_there: str | None = None
    found: dict[str, Path] = {}
    for inst in loop.instances:
        src = inst.source
        if isinstance(src, FmuFile):
            continue
        config = clocked_config(dict(src.config), src.kind, clocked and inst.role == "controller")
        path = fmu_dir / fmu_file_name(src.kind, config)
        if not os.path.lexists(path):
            continue
        check_fmu(path, src.kind, config, sources=True)
        built = built_config(path)
        if built.get("native"):
            check_sources(path, built, sources_digest())
        kind = "native" if built.get("native") else "python"
        wanted = ("native" if fmi == 3 or fmus == "native" else fmus if fmus == "python"
                  else kind_there or kind)
        if kind != wanted:
            raise BadFileError(path, _wrong_kind(kind, wanted, fmus, fmi, fmu_dir))
        if kind == "native" and built.get("fmi", 2) != fmi:
            had = built.get("fmi", 2)
            raise BadFileError(path, f"is an FMI {had}.0 FMU, this run needs FMI {fmi}.0 ("
                                     + ("--fmi 3 runs it" if had == 3 else
                                        "run without --fmi 3 to use it")
                                     + f", or rebuild the folder: delaycomp build"
                                       f"{' --fmi 3' if fmi == 3 else ''} --out {fmu_dir})")
        kind_there = kind
        found[inst.name] = path
        cache_hit(path, model_identifier(src.kind, config))
    return kind_there, found


def _wrong_kind(kind: str, wanted: str, fmus: str, fmi: int, fmu_dir: Path) -> str:
    """The reason of ``fmus_in_dir``'s error for a ``kind`` FMU where ``wanted`` ones run:
    what it is, what the run asks for, and what to do."""
    name = {"native": "native", "python": "Python"}
    if fmus == "auto" and fmi == 2:  # the first file there was of the other kind
        return (f"is a {name[kind]} FMU beside {name[wanted]} ones of this loop (rebuild the "
                f"folder: delaycomp build --out {fmu_dir}, or delete the file)")
    if wanted == "python":
        return ("is a native FMU, --python runs Python ones (run without --python to use "
                f"it, or rebuild the folder: delaycomp build --python --out {fmu_dir})")
    flag = "--fmi 3" if fmi == 3 else "--native"
    return (f"is a Python FMU, {flag} runs native ones (run without {flag} to use it, or "
            f"rebuild the folder: delaycomp build {flag} --out {fmu_dir})")


def native_or_why(loop, fmu_dir: Path | None = None, fmi: int = 2,
                  found: dict[str, Path] | None = None
                  ) -> tuple[dict[str, Path] | None, str | None]:
    """The native FMUs of ``loop`` where they can be had here (``native_fmus``), else
    ``(None, why)``: an instance without a native twin (a user's FMU file), no C compiler,
    or a model that does not translate (or CasADi missing). The commands' default: native
    where it exists, the Python FMUs otherwise."""
    from delaycomp.maths.model import ModelError

    try:
        return native_fmus(loop, fmu_dir, fmi, found=found), None
    except (ValueError, NativeBuildError, ModelError) as exc:
        return None, why_not_native(exc)


def choose(loop, fmus: str = "auto", fmu_dir: Path | None = None, fmi: int = 2,
           clocked: bool = False) -> tuple[dict[str, Path] | None, str | None]:
    """The FMU files a run of ``loop`` (a ``Loop``) with the FMU engine uses, and why not
    the native ones where it could have: ``(files, why)``, ``files`` ``None`` for the
    Python FMUs of the build cache (``delaycomp.api.choose_fmus``, which checks its
    arguments first, says the rules: ``fmus`` is ``auto``, ``native`` or ``python``; the
    FMUs of ``fmu_dir`` first, missing native ones built into ``fmu_dir/native``)."""
    native_dir = Path(fmu_dir) / "native" if fmu_dir else None
    found: dict[str, Path] = {}
    if fmu_dir:
        there, found = fmus_in_dir(loop, Path(fmu_dir), fmus, fmi, clocked)
        if there == "python" and fmus == "auto":  # what build --out left there
            try:  # the note of a loop that has no native FMUs anyway
                check_native(loop, fmi, clocked)
            except ValueError as exc:
                return None, why_not_native(exc)
            from delaycomp.progress import detail

            detail(f"the Python FMUs run this loop: {fmu_dir} holds Python ones")
            return None, None
    if fmus == "python":
        return None, None
    if fmus == "native" or fmi == 3:
        return native_fmus(loop, native_dir, fmi, clocked, found), None
    return native_or_why(loop, native_dir, found=found)


def why_not_native(exc: Exception) -> str:
    """The reason ``exc`` gives why a loop runs no native FMUs here, as the commands' note
    says it (``native_or_why``)."""
    return str(exc).splitlines()[0].removeprefix("--native is not allowed for this loop: ")


def native_fmus(loop, fmu_dir: Path | None = None, fmi: int = 2,
                clocked: bool = False, found: dict[str, Path] | None = None
                ) -> dict[str, Path]:
    """Native FMU files for every instance of ``loop`` (a ``Loop``), to pass as ``fmus=``
    to ``delaycomp.orchestrator.simulate.run_loop``, with this machine's binary alone
    (they run here; ``delaycomp build`` writes FMUs for elsewhere); FMI 3.0 ones with
    ``fmi=3``, where a user's FMU file (``FmuFile``, e.g. another tool's FMI 2.0 plant)
    keeps its file: a mixed loop; ``clocked`` (FMI 3.0): the controller driven by a clock (the LTI
    controller's variant; ``ValueError`` for a loop whose controller has none).
    ``found``: native files already checked for some instances, by name (``fmus_in_dir``:
    those ``delaycomp build --out`` wrote), taken as they are; the others from
    ``fmu_dir``.

    Raises
    ------
    ValueError
        An instance has no native twin (a user model's plant or controller, a user's FMU).
    """
    from delaycomp.system.loop import FmuFile

    check_native(loop, fmi, clocked)
    found = found or {}
    here = toolchain.this_platform()
    # FMUs to run here: this machine's binary alone (a first run compiles one platform)
    with toolchain.chosen((here,) if here else None):
        return {inst.name: found.get(inst.name) or native_fmu_path(
                    inst.source.kind,
                    clocked_config(dict(inst.source.config), inst.source.kind,
                             clocked and inst.role == "controller"), fmu_dir, fmi)
                for inst in loop.instances if not isinstance(inst.source, FmuFile)}


def check_native(loop, fmi: int = 2, clocked: bool = False) -> None:
    """``ValueError`` where ``loop`` has no native FMUs (``native_fmus``), before any
    build: an instance without a native twin, or ``clocked`` for a loop whose controller
    has no clocked variant."""
    from delaycomp.system.loop import BuiltinFmu, FmuFile, ModelFmu

    for inst in loop.instances:
        src = inst.source
        if fmi == 3 and isinstance(src, FmuFile):
            continue
        if not ((isinstance(src, BuiltinFmu) and src.kind in NATIVE_KINDS)
                or (isinstance(src, ModelFmu) and src.kind in MODEL_KINDS)):
            what = f"a {src.kind} FMU" if hasattr(src, "kind") else "a user's FMU file"
            raise ValueError(f"--native is not allowed for this loop: instance {inst.name!r} "
                             f"is {what}; native FMUs exist for the delay, the network "
                             "channel, the LTI plant and controller, the time-stamp "
                             "controller, and a model file's plant and controller")
    if clocked:
        ctrl = loop.by_role("controller")
        if ctrl is None or isinstance(ctrl.source, FmuFile) or not native_twin(
                ctrl.source.kind).clock or fmi != 3:
            raise ValueError("clocked = true is not allowed for this loop: a clocked "
                             "controller is the FMI 3.0 LTI controller (fmi = 3, an LTI "
                             "loop's controller)")
