"""Where delaycomp's modules live when they are not where an installed package has them.

The package stands in layers, each a folder, imports only downward (docs/development.md,
"Where things live"). Two places differ from an installed wheel:

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
it answers only for these names. This module imports nothing from delaycomp but the
names: it is bundled into the Python FMUs with the maths. The finder is a plain class
with the method the import system calls (``find_spec``), not a subclass of
``importlib.abc``'s, which imports ``importlib.resources`` (a third of ``delaycomp
--help``'s start).

Examples
--------
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


class _Finder:
    """Answers, in a checkout, for the folders beside it: a finder of ``sys.meta_path``
    (``find_spec``)."""

    def find_spec(self, fullname, path=None, target=None):
        if not fullname.startswith("delaycomp."):
            return None
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
