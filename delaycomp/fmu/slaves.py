"""The slave class of each FMU kind in this process: the very class an FMU wraps (the
modules under ``fmus/``, installed as ``delaycomp.fmus``), for the in-process engine
(``delaycomp.orchestrator.inprocess``) and for the native build, which writes the
modelDescription of the Python twin.
"""

from __future__ import annotations

import importlib
import importlib.util
import sys
from pathlib import Path

from delaycomp.fmu.build import FMUS, check_model_control, model_id, model_identifier
from delaycomp.version import __version__

__all__ = ["slave_class"]

_CLASSES: dict[tuple, type] = {}


def _load_model_module(model_path: str) -> str:
    """Import a model file under the unique name its FMUs bundle it as; return that name."""
    name = f"delaycomp_model_{model_id(model_path)}"  # = delaycomp.maths.model.module_name
    if name not in sys.modules:
        spec = importlib.util.spec_from_file_location(name, model_path)
        assert spec is not None and spec.loader is not None  # a .py file always has one
        module = importlib.util.module_from_spec(spec)
        sys.modules[name] = module
        try:
            spec.loader.exec_module(module)
        except BaseException:
            del sys.modules[name]
            raise
    return name


def slave_class(kind: str, config: dict) -> tuple[type, dict]:
    """The slave class of FMU ``kind`` for ``config``, and the configuration it reads.

    For a model template this is a subclass naming the model module, as ``delaycomp build``
    generates it inside the FMU.
    """
    spec = FMUS[kind]
    cfg = {**config, "version": __version__}
    key = (kind, tuple(sorted((k, str(v)) for k, v in cfg.items())))
    module = importlib.import_module(f"delaycomp.fmus.{spec.kind}.{spec.script_path.stem}")
    if not spec.template:
        return getattr(module, spec.model_identifier), cfg
    model_path = str(Path(cfg.pop("model")).resolve())
    check_model_control(kind, model_path)
    cfg["model_name"] = Path(model_path).stem
    cfg["model_id"] = model_id(model_path)
    cls = _CLASSES.get(key)
    if cls is None:
        base = getattr(module, spec.template)
        cls = type(model_identifier(kind, {"model": model_path}), (base,),
                   {"model_module": _load_model_module(model_path)})
        _CLASSES[key] = cls
    return cls, cfg
