"""The API's writers: a loop's FMUs and wiring sheet (``build``), its controller as plain
C (``export_c``), the loop with its FMUs as an SSP archive (``to_ssp``)."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path

from delaycomp.api._common import LoopLike, as_loop, fmi_version, fmu_kind
from delaycomp.errors import ParameterError
from delaycomp.names import array_element
from delaycomp.system import Loop


def build(loop: LoopLike, out: str | Path, *, only: Sequence[str] | None = None,
          fmus: str = "auto", info: Callable[[str], None] | None = None,
          sets: Sequence[str] | Mapping[str, object] = (), fmi: int = 2,
          clocked: bool = False, platforms: str | Sequence[str] | None = None):
    """Write the FMUs of ``loop`` into the folder ``out``, named after the loop
    (``<name>_plant.fmu``, ``<name>_meas_delay.fmu``, ``<name>_controller.fmu``,
    ``<name>_input_delay.fmu``) with the loop's values as their start values, and
    ``<name>_wiring.txt``: each FMU's inputs and outputs, the connections, T and the base
    step a host must use, and the delays a host provides when it takes only the
    controller. ``delaycomp build LOOP.toml`` on the command line.

    Parameters
    ----------
    loop : Loop, str or Path
        The loop (``load``, ``lti``, ``model``), a loop file's path or a
        scenario's name; its ``name`` names the files.
    out : path
        Output folder (created; files of those names are replaced).
    only : sequence of str, optional
        ``"plant"``, ``"controller"``, ``"delays"``: only these (default: all).
    fmus : str
        As for ``run``: the native C FMUs where they exist (``auto``; the Python ones
        with a note in ``.notes`` otherwise), only native ones, or the Python ones.
    info : callable, optional
        Hears what is being built, one line at a time (the command line's ``-v``).
    sets : sequence of str or mapping, optional
        Overrides, as ``load`` takes them.
    fmi : int, optional
        2 (default) or 3: FMI 3.0 FMUs (native C only, ``delaycomp.fmu.fmi3``: the
        matrices and vectors as arrays sized by structural parameters).
    clocked : bool, optional
        With ``fmi=3``: the controller's clocked variant (its sampling driven by an FMI 3.0
        clock of interval T; LTI controllers).
    platforms : str or sequence of str, optional
        The native FMUs' binaries (``--platforms``): platform tuples (``x86_64-linux``,
        ``aarch64-linux``, ``x86_64-windows``, ``x86_64-darwin``, ``aarch64-darwin``) or
        FMI 2.0 names (``linux64``, ``win64``, ``darwin64``), a list or one
        comma-separated string; default all five (``delaycomp.fmu.toolchain``).

    Returns
    -------
    delaycomp.formats.loopbuild.LoopBuild
        ``.fmus`` (role -> path), ``.wiring``, ``.native``, ``.notes``.

    Examples
    --------
    >>> import tempfile
    >>> from delaycomp import api
    >>> loop = api.lti([[0.0, 1.0], [0.0, 0.0]], [[0.0], [1.0]], [[-1.0, -1.6]], T=0.2,
    ...                r=0.36, tau=0.4, N=20, x0=[1.0, 0.0], name="dbl")
    >>> out = api.build(loop, tempfile.mkdtemp(), only=["controller"], fmus="python")
    >>> sorted(p.name for p in out.paths)
    ['dbl_controller.fmu', 'dbl_wiring.txt']
    """
    from delaycomp.formats.loopbuild import build_loop

    fmi = fmi_version(fmi, clocked)
    if fmi == 3 and fmus == "python":
        raise ParameterError("fmi = 3 is not allowed with fmus = python: delaycomp's FMI 3.0 "
                             "FMUs are the native C ones")
    if platforms is None:
        return build_loop(as_loop(loop, sets), out, only=only, fmus=fmus, info=info,
                          fmi=fmi, clocked=clocked)
    from delaycomp.fmu.toolchain import NativeBuildError, chosen, parse_platforms

    text = platforms if isinstance(platforms, str) else ",".join(platforms)
    try:
        names = parse_platforms(text, "platforms")
    except NativeBuildError as exc:
        raise ParameterError(str(exc)) from None
    if not names:
        raise ParameterError("platforms names no platform: give at least one")
    with chosen(names):
        return build_loop(as_loop(loop, sets), out, only=only, fmus=fmus, info=info,
                          fmi=fmi, clocked=clocked)


def export_c(loop: LoopLike, out: str | Path, prefix: str, *,
             sets: Sequence[str] | Mapping[str, object] = ()) -> list[Path]:
    """Write the controller of ``loop`` as plain C for an embedded target: ``out/prefix.h``
    and ``out/prefix.c`` (C99, no heap, no I/O, no global state), with ``prefix_init``,
    ``prefix_sample`` and ``prefix_output`` (the header documents them and their return
    codes). ``delaycomp export-c LOOP.toml --prefix NAME --out DIR`` on the command line;
    ``docs/howto/microcontroller.md`` shows a firmware loop.

    Parameters
    ----------
    loop : Loop, str or Path
        A loop whose controller is delaycomp's (LTI, or a model file's), a loop file's
        path or a scenario's name.
    out : path
        The folder (created).
    prefix : str
        A C identifier: the files' names and every exported name start with it.
    sets : sequence of str or mapping, optional
        Overrides, as ``load`` takes them.

    Returns
    -------
    list of Path
        ``[out/prefix.h, out/prefix.c]``.

    Examples
    --------
    >>> import tempfile
    >>> from delaycomp import api
    >>> from delaycomp.paper.scenarios import loop_file
    >>> loop = api.load(loop_file("example-3.6"), r=0.4)
    >>> [p.name for p in api.export_c(loop, tempfile.mkdtemp(), "ctl")]
    ['ctl.h', 'ctl.c']
    """
    from delaycomp.formats.exportc import export_c as _export_c

    return _export_c(as_loop(loop, sets), out, prefix)


def to_ssp(loop: LoopLike, out: str | Path, *, jacobi: bool = False,
           fmu_dir: str | Path | None = None, fmus: str = "auto",
           notes: list[str] | None = None,
           sets: Sequence[str] | Mapping[str, object] = (), fmi: int = 2,
           clocked: bool = False) -> Path:
    """Pack ``loop`` with its FMUs into the SSP archive ``out``; ``jacobi=True`` packs the
    variant that libcosim and Ecos run exactly (see ``delaycomp.system.jacobi``).
    ``fmus`` as for ``run``: the native C FMUs where they exist (``auto``: where they
    do not, the Python ones, and ``notes`` hears why), only native ones, or the Python
    ones. ``delaycomp ssp`` on the command line. ``loop``: a ``Loop``, a loop file's
    path or a scenario's name, with ``sets`` as ``load`` takes them.

    ``fmi=3``: the archive carries FMI 3.0 native FMUs (``clocked``: the controller's
    clocked variant), each with its instance's values as start values (and so a file of
    its own, ``resources/<instance>.fmu``); the SSD and the parameter sets are SSP 1.0 as
    before, the parameter sets with the scalar parameters only (SSP 1.0 knows no arrays:
    ``A``, ``B``, ``K``, ``x0``, ``u0`` are the FMUs' start values)."""
    from delaycomp.formats import ssp
    fmu_kind(fmus)
    fmi = fmi_version(fmi, clocked)
    loop = as_loop(loop, sets)
    fmu_dir = Path(fmu_dir) if fmu_dir else None
    if fmi == 3:
        return _to_ssp3(loop, out, jacobi, fmus, clocked)
    if jacobi:
        from delaycomp.verify.thirdparty import pack_jacobi

        path = pack_jacobi(loop, out, fmu_dir)
    else:
        path = ssp.pack(*ssp.loop_system(loop), out, fmu_dir)
    if fmus != "python":  # the same archive with the native twins of its FMUs
        from delaycomp.fmu.native import NativeBuildError, native_archive

        try:
            native_archive(path, path)
        except (ValueError, NativeBuildError) as exc:  # ModelError is a ValueError
            Path(path).with_name(Path(path).name + ".part").unlink(missing_ok=True)
            if fmus == "native":
                Path(path).unlink()
                raise
            if notes is not None:
                notes.append("the archive holds the Python FMUs (no native ones here: "
                             f"{str(exc).splitlines()[0]})")
    return path


def _to_ssp3(loop: Loop, out: str | Path, jacobi: bool, fmus: str, clocked: bool) -> Path:
    """``to_ssp`` with FMI 3.0 FMUs: built with the loop's values as start values, packed
    beside the same SSD and parameter sets."""
    from delaycomp.formats import ssp
    from delaycomp.formats.loopbuild import native_with_starts
    from delaycomp.tmpfiles import temp_dir

    if fmus == "python":
        raise ParameterError("fmi = 3 is not allowed with fmus = python: delaycomp's FMI 3.0 "
                             "FMUs are the native C ones")
    if jacobi and clocked:
        raise ParameterError("clocked = true is not allowed with jacobi = true: the Jacobi "
                             "variant samples the step before each tick, a clocked controller "
                             "samples at the tick (pack one or the other)")
    spec, info = ssp.loop_system(loop)
    if jacobi:
        from delaycomp.verify.thirdparty import jacobi_variant

        spec, info = jacobi_variant(spec), ssp.jacobi_info(info)
    with temp_dir("delaycomp-ssp3-") as tmp:
        try:
            built = native_with_starts(spec, Path(tmp), fmi=3, clocked=clocked)
        except ValueError as exc:  # no native twin, or no clocked variant
            raise ParameterError(f"{str(exc).splitlines()[0]} (ssp with fmi = 3)") from None
        # SSP 1.0 knows no arrays: the parameter sets hold the scalars, the arrays travel
        # as the FMUs' start values (an element such as A[1,1] names no FMI 3.0 variable)
        scalars = spec.with_instances(
            dataclasses.replace(i, parameters={k: v for k, v in i.parameters.items()
                                               if array_element(k) is None})
            if i.name in built else i for i in spec.instances)
        return ssp.pack(scalars, info, out, fmus=built, own_files=True)
