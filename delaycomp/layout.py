"""Where delaycomp's modules live, and the names they had before the layers became folders.

The package stands in layers, each a folder, imports only downward (docs/development.md,
"Where things live"). Two things keep older scripts and a plain checkout working:

- **Earlier names.** Each module's name before 0.2 (``delaycomp.lti``,
  ``delaycomp.simulate``, ``delaycomp.models.unicycle``, ...) still imports, as the very
  module at its new place (``MOVED``): the same objects, so a patch or an
  ``isinstance`` through either name sees the other.
- **A Python FMU's part of the package.** An FMU bundles part of the package (the maths
  and the base slave) beside its ``delaycomp_fmu.json``, and its binary puts that folder
  first on ``sys.path`` of the process that runs it; processes started from there copy
  that ``sys.path``. In such a bundled copy, each package the FMU bundles in part also
  takes the same package's folders that ``sys.path`` and the other import finders hold
  (``whole``), so those processes still find every module.
- **A checkout as it installs.** The repository keeps ``orchestrator/``, ``fmus/`` and
  ``reference/`` at its top (``BESIDE``); installed, they are ``delaycomp.orchestrator``,
  ``delaycomp.fmus`` and ``delaycomp.reference``. Run from a checkout that is not installed
  (``PYTHONPATH=.``), those names resolve to the top-level folders, as they do installed.

``install`` puts the finder first on ``sys.meta_path`` (``import delaycomp`` calls it);
it answers only for these names. This module imports nothing from delaycomp: it is bundled
into the Python FMUs with the maths. The finder and its loader are plain classes with the
methods the import system calls (``find_spec``; ``create_module``, ``exec_module``), not
subclasses of ``importlib.abc``'s, which imports ``importlib.resources`` (a third of
``delaycomp --help``'s start, issue 50).

Examples
--------
>>> import delaycomp.grid, delaycomp.maths.grid
>>> delaycomp.grid is delaycomp.maths.grid
True

Four earlier names are API names now (``delaycomp.lti``, ``delaycomp.model``,
``delaycomp.build``, ``delaycomp.sweep``): they import as the modules
(``importlib.import_module("delaycomp.lti")``), while the attribute ``delaycomp.lti`` is
the API function (``delaycomp/__init__.py``).
>>> import delaycomp.orchestrator.master
>>> delaycomp.orchestrator.master.__name__
'delaycomp.orchestrator.master'
"""

from __future__ import annotations

import importlib
import importlib.machinery
import importlib.util
import os
import pkgutil
import sys

from delaycomp.names import CONFIG_NAME

#: each earlier module name -> the module's name now (a package's submodules follow it)
MOVED = {
    "delaycomp.grid": "delaycomp.maths.grid",
    "delaycomp.lti": "delaycomp.maths.lti",
    "delaycomp.history": "delaycomp.maths.history",
    "delaycomp.delayline": "delaycomp.maths.delayline",
    "delaycomp.model": "delaycomp.maths.model",
    "delaycomp.predictors": "delaycomp.maths.predictors",
    "delaycomp.controller": "delaycomp.maths.zoh",
    "delaycomp.nlcontrol": "delaycomp.maths.nlcontrol",
    "delaycomp.scenarios": "delaycomp.paper.scenarios",
    "delaycomp.models": "delaycomp.paper.models",
    "delaycomp.fmuslave": "delaycomp.fmu.slave",
    "delaycomp.build": "delaycomp.fmu.build",
    "delaycomp.translate": "delaycomp.fmu.translate",
    "delaycomp.native": "delaycomp.fmu.native",
    "delaycomp.simulate": "delaycomp.orchestrator.simulate",
    "delaycomp.ssp": "delaycomp.formats.ssp",
    "delaycomp.outputs": "delaycomp.formats.outputs",
    "delaycomp.loopbuild": "delaycomp.formats.loopbuild",
    "delaycomp.exportc": "delaycomp.formats.exportc",
    "delaycomp.sweep": "delaycomp.studies.sweep",
    "delaycomp.sweep_batch": "delaycomp.studies.sweep_batch",
    "delaycomp.batch": "delaycomp.studies.batch",
    "delaycomp.critical": "delaycomp.studies.critical",
    "delaycomp.cases": "delaycomp.verify.cases",
    "delaycomp.check": "delaycomp.verify.check",
    "delaycomp.crosscheck": "delaycomp.verify.crosscheck",
    "delaycomp.container": "delaycomp.verify.container",
    "delaycomp.thirdparty": "delaycomp.verify.thirdparty",
    "delaycomp.omsimulator": "delaycomp.verify.omsimulator",
}
#: subpackages that a checkout keeps beside ``delaycomp/`` (at the repository's top)
BESIDE = ("orchestrator", "fmus", "reference")

_PACKAGE_DIR = os.path.dirname(os.path.abspath(__file__))
_ROOT = os.path.dirname(_PACKAGE_DIR)


def bundled() -> bool:
    """Whether this copy of the package is the part a Python FMU bundles."""
    return os.path.isfile(os.path.join(_ROOT, CONFIG_NAME))


def whole(name: str, path: list[str]) -> list[str]:
    """The search path of package ``name`` (its ``__path__``): as it is, or, in an FMU's
    bundled copy, followed by the same package's folders further down ``sys.path``
    (``pkgutil.extend_path``) and those the other finders on ``sys.meta_path`` hold
    (an editable install's). The bundled folder stays first: the FMU's own modules win.

    >>> import delaycomp
    >>> whole("delaycomp", delaycomp.__path__) == delaycomp.__path__  # not a bundle
    True
    """
    if not bundled():
        return path
    out = pkgutil.extend_path(list(path), name)
    for finder in sys.meta_path:
        if finder is importlib.machinery.PathFinder or isinstance(finder, _Finder):
            continue  # extend_path did the path finder's part; ours holds no folders
        try:
            spec = finder.find_spec(name, None)
        except Exception:  # noqa: BLE001 - a foreign finder's failure: it holds nothing
            continue
        for folder in (spec.submodule_search_locations or []) if spec else []:
            if folder not in out:
                out.append(folder)
    return out


def now(name: str) -> str | None:
    """The module's name now, for an earlier ``name`` (or one of its submodules); ``None``
    for a name that did not move.

    >>> now("delaycomp.models.unicycle")
    'delaycomp.paper.models.unicycle'
    >>> now("delaycomp.maths.lti") is None
    True
    """
    head, _, rest = name.partition(".")
    if head != "delaycomp" or not rest:
        return None
    parts = name.split(".")
    for i in range(len(parts), 1, -1):
        new = MOVED.get(".".join(parts[:i]))
        if new is not None:
            return ".".join([new, *parts[i:]])
    return None


class _Same:
    """Loads an earlier name as the module at its new place (imported by then): a loader
    of the import system (``create_module``, ``exec_module``)."""

    def __init__(self, target: str):
        self.target = target
        self._spec: importlib.machinery.ModuleSpec | None = None

    def create_module(self, spec):
        module = importlib.import_module(self.target)
        self._spec = module.__spec__
        return module

    def exec_module(self, module) -> None:
        module.__spec__ = self._spec  # the import machinery set the earlier name's spec


class _Finder:
    """Answers for the earlier names and, in a checkout, for the folders beside it: a
    finder of ``sys.meta_path`` (``find_spec``)."""

    def find_spec(self, fullname, path=None, target=None):
        if not fullname.startswith("delaycomp."):
            return None
        new = now(fullname)
        if new is not None:
            # typeshed's loader protocol asks for load_module, which the import system
            # calls only on loaders without exec_module
            return importlib.util.spec_from_loader(fullname, _Same(new))  # type: ignore[arg-type]
        name = fullname[len("delaycomp."):]
        if name in BESIDE and not os.path.isdir(os.path.join(_PACKAGE_DIR, name)):
            folder = os.path.join(_ROOT, name)
            init = os.path.join(folder, "__init__.py")
            if os.path.isfile(init) and os.path.isfile(os.path.join(_ROOT, "pyproject.toml")):
                return importlib.util.spec_from_file_location(
                    fullname, init, submodule_search_locations=[folder])
        return None


def install() -> None:
    """Put the finder first on ``sys.meta_path`` (once per process)."""
    if not any(isinstance(f, _Finder) for f in sys.meta_path):
        sys.meta_path.insert(0, _Finder())
