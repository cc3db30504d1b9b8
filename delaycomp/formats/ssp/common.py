"""What the SSP writer and reader share: the namespaces and the tag helper, the names
of an archive's parts, parameter values as SSV writes them, the String parameters'
Integer twins and the header of a system (``SystemInfo``).
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from lxml import etree

from delaycomp.errors import SspError
from delaycomp.names import INDEX_SUFFIX

SSD_NS = "http://ssp-standard.org/SSP1/SystemStructureDescription"
SSC_NS = "http://ssp-standard.org/SSP1/SystemStructureCommon"
SSV_NS = "http://ssp-standard.org/SSP1/SystemStructureParameterValues"
OSP_NS = "http://opensimulationplatform.com/SSP/OSPAnnotations"
#: OMSimulator's namespace (the one its own writer declares)
OMS_NS = "https://raw.githubusercontent.com/OpenModelica/OMSimulator/master/schema/oms.xsd"
#: the project's own namespace for the master annotation
DC_NS = "urn:delaycomp:ssp:1"
NSMAP = {"ssd": SSD_NS, "ssc": SSC_NS, "ssv": SSV_NS, "osp": OSP_NS, "oms": OMS_NS,
         "dc": DC_NS}
#: annotation types
DC_ANNOTATION = "org.delaycomp.master"
OSP_ANNOTATION = "com.opensimulationplatform"
OMS_ANNOTATION = "org.openmodelica"
SSD_NAME = "SystemStructure.ssd"
RESOURCES = "resources"
DEFAULT_SET = "default"
FMU_MIME = "application/x-fmu-sharedlibrary"
#: FMU kinds whose build config names a model file (``config["model"]``)
_MODEL_PREFIX = "builtin:"


def tag(name: str) -> str:
    """``"ssd:System"`` -> ``"{http://...SystemStructureDescription}System"``."""
    prefix, _, local = name.partition(":")
    return f"{{{NSMAP[prefix]}}}{local}"


def ssv_type(value) -> str:
    """The SSV element name of a parameter value (Boolean, Integer, Real, String)."""
    if isinstance(value, bool):
        return "Boolean"
    if isinstance(value, int):
        return "Integer"
    if isinstance(value, float):
        return "Real"
    if isinstance(value, str):
        return "String"
    raise TypeError(f"parameter value {value!r} has no SSV type")


def format_value(value) -> str:
    """A parameter value as SSV writes it (a float by its shortest repr: it reads back
    bit-identically)."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        if not math.isfinite(value):
            raise ValueError(f"parameter value {value!r} is not finite")
        return repr(value)  # shortest repr: reads back bit-identically
    return str(value)


def parse_value(kind: str, text: str):
    """The typed value of an SSV ``value`` attribute of element ``kind``."""
    if kind == "Real":
        return float(text)
    if kind == "Integer":
        return int(text)
    if kind == "Boolean":
        if text not in ("true", "false", "1", "0"):
            raise SspError(f"Boolean value {text!r} is not true/false")
        return text in ("true", "1")
    return text


def ssd_identifier(name: str) -> str:
    """``name`` as an identifier for the SSD's model and system (OMSimulator's command line
    refuses any other): each character outside ``[A-Za-z0-9_]`` becomes ``_``, and a name
    that starts with a digit gets a leading ``_``.

    Examples
    --------
    >>> ssd_identifier("example-3.6")
    'example_3_6'
    >>> ssd_identifier("2-loops")
    '_2_loops'
    """
    ident = re.sub(r"[^A-Za-z0-9_]", "_", name) or "_"
    return f"_{ident}" if ident[0].isdigit() else ident


def parameter_choices(key: tuple[str, dict] | None) -> dict[str, tuple[str, ...]]:
    """The String parameters with a fixed set of choices of the FMU built from ``key``
    (``source.build_key()``: kind and config; None for a user's FMU file, whose Strings
    are left as they are), in the order of their Integer twins (index 1 = the first
    choice)."""
    if key is None:
        return {}
    kind, config = key
    if kind in ("controller", "stamped_controller"):
        from delaycomp.maths.lti import MODES

        return {"mode": tuple(MODES)}
    if kind == "channel":
        from delaycomp.maths.channel import DISTRIBUTIONS, LOSS_MODELS, POLICIES

        return {"distribution": DISTRIBUTIONS, "loss_model": LOSS_MODELS, "policy": POLICIES}
    if kind in ("model_plant", "model_controller", "stamped_model_controller") \
            and "model" in config:
        from delaycomp.maths.lti import MODES
        from delaycomp.maths.model import CONTROLS, load_model
        from delaycomp.maths.nlcontrol import PREDICTORS

        choices = dict(load_model(config["model"]).choices)
        if kind == "model_controller":
            choices = {"mode": CONTROLS, "predictor": PREDICTORS, **choices}
        elif kind == "stamped_model_controller":
            choices = {"mode": tuple(MODES), **choices}
        return {k: tuple(v) for k, v in choices.items()}
    return {}


def foreign_parameters(params: Mapping[str, Any],
                       choices: dict[str, tuple[str, ...]]) -> dict:
    """``params`` as an importer without String parameters can apply them: each String
    with ``choices`` becomes its Integer twin ``<name>_index`` (1-based), in its place.
    A String without choices, or with a value outside them, stays a String (the FMU then
    reports the bad value)."""
    out = {}
    for name, value in params.items():
        if isinstance(value, str) and value in choices.get(name, ()):
            out[f"{name}{INDEX_SUFFIX}"] = choices[name].index(value) + 1
        else:
            out[name] = value
    return out


def native_parameters(params: dict, choices: dict[str, tuple[str, ...]], where: str) -> dict:
    """The inverse of ``foreign_parameters``: each Integer twin back into its String
    (an index 0 leaves the String to its FMU default, so the String is omitted)."""
    out = {}
    for name, value in params.items():
        base = name[:-len(INDEX_SUFFIX)] if name.endswith(INDEX_SUFFIX) else None
        if base is None or base not in choices or isinstance(value, bool) \
                or not isinstance(value, int):
            out[name] = value
            continue
        if not 0 <= value <= len(choices[base]):
            raise SspError(f"{where}: {name} = {value} is not allowed: must be 0 .. "
                           f"{len(choices[base])} ({', '.join(choices[base])})")
        if value:
            out[base] = choices[base][value - 1]
    return out


def config_out(config: dict) -> dict:
    """The build config with a model file named without a machine path."""
    out = dict(config)
    if "model" in out:
        from delaycomp.paper.models import HERE

        path = Path(out["model"]).resolve()
        out["model"] = (f"{_MODEL_PREFIX}{path.stem}" if path.parent == HERE
                        else path.name)
    return out


def config_in(config: dict) -> dict:
    """A build configuration read back from the dc:Component annotation (a built-in
    model's name resolved to its file)."""
    out = dict(config)
    model = out.get("model")
    if isinstance(model, str) and model.startswith(_MODEL_PREFIX):
        from delaycomp.paper.models import path

        out["model"] = str(path(model[len(_MODEL_PREFIX):]))
    return out


@dataclass(frozen=True)
class SystemInfo:
    """What an SSD says beyond the loop: its name, description, stop time, set name."""

    name: str
    description: str = ""
    stop_time: float | None = None
    parameter_set: str = DEFAULT_SET


def parse_xml(path: Path) -> etree._Element:
    """The root element of the XML file at ``path``; an unreadable file is an
    ``SspError``."""
    try:
        return etree.parse(str(path)).getroot()
    except (OSError, etree.XMLSyntaxError) as exc:
        raise SspError(f"{path.name}: not readable XML: {exc}") from None


def required_attr(el: etree._Element, name: str, where: str) -> str:
    """Attribute ``name`` of ``el``; a missing one is an ``SspError``
    naming ``where``."""
    value = el.get(name)
    if value is None:
        raise SspError(f"{where}: missing attribute {name!r}")
    return value
