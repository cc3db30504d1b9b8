"""SSP 1.0 description of a closed loop: ``SystemStructure.ssd``, ``.ssv`` files, ``.ssp``:
written by ``.write``, read by ``.read``, unpacked by ``.archive``, on the names
and values of ``.common``.

The SSD and its parameter sets are written from the same ``Loop``
that the master runs, so the two cannot drift apart, and are read back into one.
This module only does XML; there is no maths here.

Layout of a system (a folder, or the zip archive ``<name>.ssp``)::

    SystemStructure.ssd          components, connectors, connections, master settings
    resources/<instance>.ssv     one parameter set per component (SSV 1.0)
    resources/<Model>.fmu        the FMUs (in the archive only)

The archive is written so that every SSP tool we know reads it as it is (our master,
libcosim, Ecos, OMSimulator's Python API and its command line):

- model and system are named by an identifier (``ssd_identifier``: ``example_3_6``; the
  archive file keeps the loop's name, ``example-3.6.ssp``);
- the master settings go into three vendor annotations:

  - ``org.openmodelica`` on the root system: ``<oms:FixedStepMaster stepSize="h">``, which
    OMSimulator needs (its command line refuses a system without it);
  - ``com.opensimulationplatform`` in the default experiment:
    ``<osp:FixedStepAlgorithm baseStepSize="h">``, which libcosim reads (only when
    ``xmlns:osp`` is declared on the root, as here);
  - ``org.delaycomp.master`` in the default experiment: ``<dc:Master T= N= h= name=>``
    with the recorded signals and one ``<dc:Component element= role= kind= config=
    choices=>`` per component, what ``delaycomp.fmu.cache.source_fmu`` needs to rebuild
    its FMU (namespace ``DC_NS``). Components carry no annotation: OMSimulator's schema
    check refuses ``ssd:Annotations`` there. (Archives written before kept ``<dc:Fmu>`` in
    each component; they are still read.)

Parameters are bound per component (``<ssd:ParameterBinding source="resources/plant.ssv">``)
and named by the FMU variable, as libcosim and Ecos expect. Every parameter set of a
system has the same name (``DEFAULT_SET`` unless told otherwise): Ecos applies the set
named in its ``init()``. The sets hold only Real, Integer and Boolean values, which every
importer applies: a String parameter with a fixed set of choices (the controller's
``mode``, ...) is written as its FMU's Integer twin ``<name>_index`` (1 = the first choice,
...; see ``foreign_parameters``) and read back as the String.
"""

from delaycomp.errors import SspError
from delaycomp.formats.ssp.archive import (
    MAX_MEMBERS,
    MAX_UNPACKED,
    Archive,
)
from delaycomp.formats.ssp.common import (
    DC_ANNOTATION,
    DC_NS,
    DEFAULT_SET,
    FMU_MIME,
    INDEX_SUFFIX,
    NSMAP,
    OMS_ANNOTATION,
    OMS_NS,
    OSP_ANNOTATION,
    OSP_NS,
    RESOURCES,
    SSC_NS,
    SSD_NAME,
    SSD_NS,
    SSV_NS,
    SystemInfo,
    config_in,
    config_out,
    foreign_parameters,
    format_value,
    native_parameters,
    parameter_choices,
    parse_value,
    parse_xml,
    required_attr,
    ssd_identifier,
    ssv_type,
    tag,
)
from delaycomp.formats.ssp.read import (
    MAX_N,
    Foreign,
    System,
    apply_sets,
    read_ssv,
    read_system,
    validate,
)
from delaycomp.formats.ssp.write import (
    jacobi_info,
    loop_system,
    pack,
    pack_scenarios,
    scenario_system,
    ssd_document,
    ssv_document,
    write_all,
    write_system,
)

__all__ = [
    "DC_ANNOTATION",
    "DC_NS",
    "DEFAULT_SET",
    "FMU_MIME",
    "INDEX_SUFFIX",
    "MAX_MEMBERS",
    "MAX_N",
    "MAX_UNPACKED",
    "NSMAP",
    "OMS_ANNOTATION",
    "OMS_NS",
    "OSP_ANNOTATION",
    "OSP_NS",
    "RESOURCES",
    "SSC_NS",
    "SSD_NAME",
    "SSD_NS",
    "SSV_NS",
    "Archive",
    "Foreign",
    "SspError",
    "System",
    "SystemInfo",
    "apply_sets",
    "config_in",
    "config_out",
    "foreign_parameters",
    "format_value",
    "jacobi_info",
    "loop_system",
    "native_parameters",
    "pack",
    "pack_scenarios",
    "parameter_choices",
    "parse_value",
    "parse_xml",
    "read_ssv",
    "read_system",
    "required_attr",
    "scenario_system",
    "ssd_document",
    "ssd_identifier",
    "ssv_document",
    "ssv_type",
    "tag",
    "validate",
    "write_all",
    "write_system",
]
