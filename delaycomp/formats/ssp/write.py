"""Writing a loop as SSP 1.0: the SSD and its SSVs (``write_system``), the archive
with its FMUs (``pack``), the paper's scenarios (``pack_scenarios``).
"""

from __future__ import annotations

import json
import shutil
import tempfile
from pathlib import Path
from typing import cast

from lxml import etree

from delaycomp.formats.ssp.common import (
    DC_ANNOTATION,
    DEFAULT_SET,
    FMU_MIME,
    NSMAP,
    OMS_ANNOTATION,
    OSP_ANNOTATION,
    RESOURCES,
    SSD_NAME,
    SSV_NS,
    SystemInfo,
    config_out,
    foreign_parameters,
    format_value,
    parameter_choices,
    ssd_identifier,
    ssv_type,
    tag,
)
from delaycomp.system import (
    FmuFile,
    Instance,
    Loop,
)
from delaycomp.tmpfiles import zip_folder


def ssv_document(name: str, parameters: dict) -> etree._ElementTree:
    """An SSV 1.0 parameter set ``name`` with one typed value per parameter."""
    root = etree.Element(tag("ssv:ParameterSet"), nsmap={"ssv": SSV_NS},
                         attrib={"version": "1.0", "name": name})
    params = etree.SubElement(root, tag("ssv:Parameters"))
    for pname, value in parameters.items():
        p = etree.SubElement(params, tag("ssv:Parameter"), name=pname)
        etree.SubElement(p, tag(f"ssv:{ssv_type(value)}"), value=format_value(value))
    return etree.ElementTree(root)


def ssd_document(spec: Loop, info: SystemInfo,
                 fmu_files: dict[str, str]) -> etree._ElementTree:
    """The SSD of ``spec``; ``fmu_files`` maps each instance to its FMU file name."""
    connectors: dict[str, list[tuple[str, str]]] = {name: [] for name in spec.names}
    for con in spec.connections:
        for port, kind in ((con.src, "output"), (con.dst, "input")):
            if (port.variable, kind) not in connectors[port.instance]:
                connectors[port.instance].append((port.variable, kind))
    for port in spec.recorded:
        have = connectors[port.instance]
        if (port.variable, "output") not in have and (port.variable, "input") not in have:
            have.append((port.variable, "output"))

    ident = ssd_identifier(info.name)
    root = etree.Element(tag("ssd:SystemStructureDescription"), nsmap=NSMAP,
                         attrib={"version": "1.0", "name": ident})
    system = etree.SubElement(root, tag("ssd:System"), name=ident)
    if info.description:
        system.set("description", info.description)
    elements = etree.SubElement(system, tag("ssd:Elements"))
    choices = {i.name: parameter_choices(i.source.build_key()) for i in spec.instances}
    for inst in spec.instances:
        comp = etree.SubElement(elements, tag("ssd:Component"), name=inst.name, type=FMU_MIME,
                                source=f"{RESOURCES}/{fmu_files[inst.name]}")
        conns = etree.SubElement(comp, tag("ssd:Connectors"))
        for var, ckind in connectors[inst.name]:
            c = etree.SubElement(conns, tag("ssd:Connector"), name=var, kind=ckind)
            etree.SubElement(c, tag("ssc:Real"))
        for pname, value in foreign_parameters(inst.parameters, choices[inst.name]).items():
            c = etree.SubElement(conns, tag("ssd:Connector"), name=pname, kind="parameter")
            etree.SubElement(c, tag(f"ssc:{ssv_type(value)}"))
        bindings = etree.SubElement(comp, tag("ssd:ParameterBindings"))
        etree.SubElement(bindings, tag("ssd:ParameterBinding"),
                         source=f"{RESOURCES}/{inst.name}.ssv")
    connections = etree.SubElement(system, tag("ssd:Connections"))
    for con in spec.connections:
        etree.SubElement(connections, tag("ssd:Connection"), startElement=con.src.instance,
                         startConnector=con.src.variable, endElement=con.dst.instance,
                         endConnector=con.dst.variable)

    h = spec.T / spec.N
    _oms_annotation(system, h)
    exp = etree.SubElement(root, tag("ssd:DefaultExperiment"), startTime="0.0")
    if info.stop_time is not None:
        exp.set("stopTime", format_value(float(info.stop_time)))
    anns = etree.SubElement(exp, tag("ssd:Annotations"))
    osp = etree.SubElement(anns, tag("ssc:Annotation"), type=OSP_ANNOTATION)
    alg = etree.SubElement(osp, tag("osp:Algorithm"))
    etree.SubElement(alg, tag("osp:FixedStepAlgorithm"), baseStepSize=format_value(h))
    dc = etree.SubElement(anns, tag("ssc:Annotation"), type=DC_ANNOTATION)
    master = etree.SubElement(dc, tag("dc:Master"), T=format_value(float(spec.T)), N=str(spec.N),
                              h=format_value(h), parameterSet=info.parameter_set,
                              name=info.name)
    for port in spec.recorded:
        record = etree.SubElement(master, tag("dc:Record"), element=port.instance,
                                  connector=port.variable)
        if spec.column(port) != str(port):  # a labelled column (Loop.labels)
            record.set("name", spec.column(port))
    for inst in spec.instances:
        _component_annotation(master, inst, choices[inst.name])
    return etree.ElementTree(root)


def _component_annotation(master: etree._Element, inst: Instance,
                          choices: dict[str, tuple[str, ...]]) -> None:
    """``<dc:Component element= role= kind= config= choices=>``: which FMU an instance is
    (no kind and config for a user's FMU file, but its ``tolerance`` where one is given:
    SSP 1.0 has no place for a component's tolerance) and its String choices."""
    comp = etree.SubElement(master, tag("dc:Component"), element=inst.name, role=inst.role)
    key = inst.source.build_key()
    if key is not None:
        comp.set("kind", key[0])
        comp.set("config", json.dumps(config_out(key[1]), sort_keys=True))
    elif isinstance(inst.source, FmuFile) and inst.source.tolerance is not None:
        comp.set("tolerance", format_value(float(inst.source.tolerance)))
    comp.set("choices", json.dumps(choices, sort_keys=True))


def _oms_annotation(system: etree._Element, h: float) -> None:
    """OMSimulator's master settings on the root system (its command line needs them)."""
    anns = etree.SubElement(system, tag("ssd:Annotations"))
    ann = etree.SubElement(anns, tag("ssc:Annotation"), type=OMS_ANNOTATION)
    info = etree.SubElement(etree.SubElement(ann, tag("oms:Annotations")),
                            tag("oms:SimulationInformation"))
    etree.SubElement(info, tag("oms:FixedStepMaster"), description="oms-ma",
                     stepSize=format_value(h))


def _fmu_file_names(spec: Loop) -> dict[str, str]:
    from delaycomp.fmu.cache import fmu_file_name

    return {i.name: (Path(i.source.path).name if isinstance(i.source, FmuFile)
                     else fmu_file_name(*i.source.build_key())) for i in spec.instances}


def _write(tree: etree._ElementTree, path: Path) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(etree.tostring(tree, xml_declaration=True, encoding="UTF-8",
                                    pretty_print=True))


def write_system(spec: Loop, info: SystemInfo, folder: str | Path,
                 names: dict[str, str] | None = None) -> Path:
    """Write ``SystemStructure.ssd`` and ``resources/<instance>.ssv`` into ``folder``
    (``names``: instance -> its FMU's file name in ``resources/``, default one file per
    build key)."""
    folder = Path(folder)
    _write(ssd_document(spec, info, names or _fmu_file_names(spec)), folder / SSD_NAME)
    for inst in spec.instances:
        ssv = foreign_parameters(inst.parameters, parameter_choices(inst.source.build_key()))
        _write(ssv_document(info.parameter_set, ssv), folder / RESOURCES / f"{inst.name}.ssv")
    return folder / SSD_NAME


def pack(spec: Loop, info: SystemInfo, out: str | Path,
         fmu_dir: Path | None = None, fmus: dict[str, Path] | None = None,
         own_files: bool = False) -> Path:
    """Write the archive ``out`` (``.ssp``): the SSD, its SSVs and the FMUs.

    The FMUs are taken from ``fmus`` (instance -> path) where given, else from
    ``delaycomp.fmu.cache.source_fmu`` (built into ``fmu_dir`` or the cache if missing).
    Instances of one build key share one file, unless ``own_files``: then each of
    ``fmus`` is ``resources/<instance>.fmu`` (FMUs that carry their instance's values as
    start values).
    """
    from delaycomp.fmu.cache import source_fmu

    out = Path(out)
    names = _fmu_file_names(spec)
    if own_files:
        names.update({name: f"{name}.fmu" for name in fmus or {}})
    with tempfile.TemporaryDirectory(prefix="delaycomp-ssp-") as tmp:
        folder = Path(tmp)
        write_system(spec, info, folder, names)
        for inst in spec.instances:
            src = (fmus or {}).get(inst.name) or source_fmu(inst.source, fmu_dir)
            target = folder / RESOURCES / names[inst.name]
            if not target.exists():
                shutil.copyfile(src, target)
        out.parent.mkdir(parents=True, exist_ok=True)
        zip_folder(folder, out)
    return out


def scenario_system(name: str, assignments: list[str] | None = None,
                    parameter_set: str = DEFAULT_SET) -> tuple[Loop, SystemInfo]:
    """The loop and SSD header of scenario ``name`` with ``NAME=VALUE`` assignments."""
    from delaycomp.paper import scenarios
    return loop_system(scenarios.get(name).loop(list(assignments or [])), parameter_set)


def loop_system(loop: Loop, parameter_set: str = DEFAULT_SET) -> tuple[Loop, SystemInfo]:
    """A loop and the SSD header it gets (its name, title and stop time)."""
    return loop, SystemInfo(loop.name, loop.title, loop.stop_time, parameter_set)


def write_all(folder: str | Path) -> list[Path]:
    """``folder/<scenario>/`` with the SSD and SSVs of every scenario at its defaults."""
    from delaycomp.paper.scenarios import SCENARIOS

    return [write_system(*scenario_system(name), Path(folder) / name) for name in SCENARIOS]


def pack_scenarios(out_dir: str | Path, fmu_dir: Path | None = None) -> list[Path]:
    """``out_dir/<scenario>.ssp`` for every scenario at its defaults, and its Jacobi variant
    ``out_dir/<scenario>-jacobi.ssp`` for libcosim and Ecos (``delaycomp.verify.thirdparty``).

    The FMUs come from ``fmu_dir`` where they are (``delaycomp build`` has just built the
    LTI loop's there) and are otherwise built, two at a time, into the build cache.
    """
    from concurrent.futures import ThreadPoolExecutor

    from delaycomp.fmu.cache import fmu_file_name, fmu_path
    from delaycomp.paper.scenarios import SCENARIOS

    systems = [scenario_system(name) for name in SCENARIOS]
    wanted: dict[str, tuple[str, dict]] = {}
    for spec, _ in systems:
        for inst in spec.instances:
            key = inst.source.build_key()
            assert key is not None  # a scenario's FMUs are all built (no FmuFile)
            kind, config = key
            wanted.setdefault(fmu_file_name(kind, config), (kind, config))
    have = {name: Path(fmu_dir) / name for name in wanted
            if fmu_dir is not None and (Path(fmu_dir) / name).is_file()}
    missing = [kc for name, kc in wanted.items() if name not in have]
    with ThreadPoolExecutor(max_workers=2) as pool:  # each build is its own process
        built = list(pool.map(lambda kc: fmu_path(*kc), missing))
    have.update({p.name: p for p in built})
    from delaycomp.system.jacobi import jacobi_variant

    out = []
    for spec, info in systems:
        # a scenario's FMUs are all built (no FmuFile, whose key is None)
        fmus = {inst.name: have[fmu_file_name(*cast("tuple[str, dict]",
                                                    inst.source.build_key()))]
                for inst in spec.instances}
        out.append(pack(spec, info, Path(out_dir) / f"{info.name}.ssp", fmus=fmus))
        variant = jacobi_variant(spec)
        out.append(pack(variant, jacobi_info(info), Path(out_dir) / f"{info.name}-jacobi.ssp",
                        fmus={i: fmus[i] for i in variant.names}))
    return out


def jacobi_info(info: SystemInfo) -> SystemInfo:
    """The SSD header of a Jacobi variant: the description says what was changed."""
    return SystemInfo(info.name, f"{info.description} (Jacobi variant: measurement delay "
                      "shortened by h, controller samples the previous step)",
                      info.stop_time, info.parameter_set)
