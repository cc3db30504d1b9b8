"""The byte layout of a native FMU's serialized state, mirrored in Python (a test helper).

``fmi2SerializeFMUstate`` of a native FMU (``fmus/native/fmi2.c``) writes its ``Snapshot``
as it lies in memory: the ``Header`` (magic ``DCNATIV1``, the GUID, ``sizeof(Data)``, the
buffer's length ``nbuf``), the instance's ``Data`` (the state machine's state, ``t0``, the
time, every variable by value reference, the String values, then the model's own
``ModelData``, ``fmus/<kind>/<name>.h``) and the model buffer of ``nbuf`` doubles. The
structures are rebuilt here with ``ctypes``, which lays out a C struct as this
platform's compiler does (the same sizes, alignment and padding), from the FMU's own
``sources/config.h`` (``NVR``, ``NSTRING``, ``NIN``, ``NOUT``, ``MODEL_HEADER``) and the
models' field lists below: a change of a ``ModelData`` must be made here too
(``decode`` checks ``sizeof(Data)`` and the length against the blob's header).

``mutations`` derives structure-aware mutations of a state (each field at its
boundary values, buffers dropped, truncated, extended or swapped); ``run_batch`` tries
them against one instance in a child process (``python tests/native_state.py SPEC``), so
that a crash fails the test (``tests/test_state_structure.py``) instead of killing pytest.
"""

from __future__ import annotations

import ctypes
import json
import math
import re
import struct
import sys
import zipfile
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

#: the native models' ModelData, field by field, as in fmus/<kind>/<name>.h: (name, C
#: type, array length: None for a scalar, "NX" or "NU" for the model's dimensions)
MODEL_DATA: dict[str, list[tuple[str, Any, str | None]]] = {
    "plant_lti.h": [("has_h", ctypes.c_int, None), ("h", ctypes.c_double, None)],
    "model_plant.h": [("branch", ctypes.c_int, None)],
    "delay.h": [("has_line", ctypes.c_int, None), ("D", ctypes.c_long, None),
                ("h", ctypes.c_double, None), ("head", ctypes.c_long, None)],
    "channel.h": [("has_line", ctypes.c_int, None), ("h", ctypes.c_double, None),
                  ("P", ctypes.c_long, None), ("Q", ctypes.c_long, None),
                  ("cap", ctypes.c_long, None), ("k", ctypes.c_longlong, None),
                  ("bad", ctypes.c_int, None), ("has_current", ctypes.c_int, None),
                  ("count", ctypes.c_long, None)],
    "controller_lti.h": [
        ("built", ctypes.c_int, None), ("l", ctypes.c_long, None),
        ("q", ctypes.c_long, None), ("L", ctypes.c_long, None),
        ("r_tilde", ctypes.c_double, None), ("padding", ctypes.c_double, None),
        ("released", ctypes.c_int, None), ("pad_line", ctypes.c_double, "NU"),
        ("next", ctypes.c_long, None),
        ("at_sample", ctypes.c_int, None), ("proposal_valid", ctypes.c_int, None),
        ("proposal", ctypes.c_double, "NU"), ("y_held_valid", ctypes.c_int, None),
        ("y_held", ctypes.c_double, "NX"), ("held", ctypes.c_double, "NU"),
        ("hist_head", ctypes.c_long, None)],
    "controller_stamped.h": [
        ("built", ctypes.c_int, None), ("L", ctypes.c_long, None),
        ("next", ctypes.c_long, None), ("at_sample", ctypes.c_int, None),
        ("proposal_valid", ctypes.c_int, None), ("proposal", ctypes.c_double, "NU"),
        ("y_held_valid", ctypes.c_int, None), ("y_held", ctypes.c_double, "NX"),
        ("stamp_held", ctypes.c_double, None), ("held", ctypes.c_double, "NU"),
        ("hist_head", ctypes.c_long, None), ("z", ctypes.c_double, "NX"),
        ("stamp", ctypes.c_double, None)],
    "model_controller.h": [
        ("built", ctypes.c_int, None), ("branch", ctypes.c_int, None),
        ("zoh", ctypes.c_int, None), ("predictor", ctypes.c_int, None),
        ("N", ctypes.c_long, None), ("h", ctypes.c_double, None),
        ("tau_eff", ctypes.c_double, None), ("W", ctypes.c_long, None),
        ("D", ctypes.c_long, None), ("k_tick", ctypes.c_long, None),
        ("hist_head", ctypes.c_long, None), ("pad_head", ctypes.c_long, None),
        ("z", ctypes.c_double, "NX"), ("held", ctypes.c_double, "NU"),
        ("cache_valid", ctypes.c_int, None), ("cache_z", ctypes.c_double, "NX"),
        ("cache_u", ctypes.c_double, "NU"), ("y_held_valid", ctypes.c_int, None),
        ("y_held", ctypes.c_double, "NX")],
}
#: (NX, NU) of each model from config.h's NIN and NOUT (its <name>.h's #define NX, NU)
DIMENSIONS = {"plant_lti.h": ("NOUT", "NIN"), "model_plant.h": ("NOUT", "NIN"),
              "delay.h": ("NIN", "NIN"), "channel.h": ("NIN", "NIN"),
              "controller_lti.h": ("NIN", "NOUT"),
              "controller_stamped.h": ("NIN - 1", "NOUT"),  # y1 .. yn and the stamp in
              "model_controller.h": ("NIN", "NOUT")}
STRING_MAX = 256  # fmus/native/native.h
#: the FMI 2.0 co-simulation states of fmi2.c (FsmState)
STATES = {"instantiated": 1, "initialization mode": 2, "step complete": 4, "terminated": 8,
          "error": 16}

INT_MAX, INT_MIN = 2**31 - 1, -(2**31)
LONG_MAX, LONG_MIN = 2**63 - 1, -(2**63)
#: the boundary values of each kind of field
INTS = [0, 1, -1, 2, INT_MAX, INT_MIN]
LONGS = [0, 1, -1, 2, LONG_MAX, LONG_MIN, 10**6, 10**6 + 1, 2**31]
DOUBLES = [0.0, -0.0, 1.0, -1.0, 5e-324, 1.7976931348623157e308, math.inf, -math.inf,
           math.nan]
STRINGS = [b"", b"bogus", b"x" * (STRING_MAX - 1), b"x" * STRING_MAX, b"\xff\n",
           b"compensated", b"uncompensated", b"zoh", b"continuous", b"closed", b"numerical",
           b"none", b"square", b"sin", b"corrected", b"uniform", b"gamma", b"trace",
           b"bernoulli", b"gilbert_elliott", b"drop_stale"]


class Header(ctypes.Structure):
    """fmi2.c's Header."""

    _fields_ = [("magic", ctypes.c_ubyte * 8), ("token", ctypes.c_ubyte * 64),
                ("data_size", ctypes.c_uint64), ("nbuf", ctypes.c_uint64)]


@dataclass
class Layout:
    """The state layout of one native FMU build (its ``Snapshot`` without the buffer)."""

    defines: dict[str, str]
    header_name: str
    nx: int
    nu: int
    data: Any  # ctypes Structure classes, made at run time
    snapshot: Any

    @property
    def size(self) -> int:
        """``sizeof(Snapshot)``: the bytes before the buffer."""
        return ctypes.sizeof(self.snapshot)


def config_defines(fmu: Path) -> dict[str, str]:
    """The ``#define``s of the FMU's ``sources/config.h``."""
    with zipfile.ZipFile(fmu) as zf:
        text = zf.read("sources/config.h").decode("utf-8")
    return dict(re.findall(r"^#define (\w+) (.+)$", text, re.M))


def layout_of(fmu: Path) -> Layout:
    """The layout of the states of the native FMU ``fmu`` (a ``.fmu`` file)."""
    defines = config_defines(fmu)
    header_name = json.loads(defines["MODEL_HEADER"])
    nvr, nstring = int(defines["NVR"]), int(defines["NSTRING"])
    nx, nu = (int(defines[name]) if " - " not in name
              else int(defines[name.split(" - ")[0]]) - int(name.split(" - ")[1])
              for name in DIMENSIONS[header_name])
    sizes = {"NX": nx, "NU": nu}
    model = type("ModelData", (ctypes.Structure,), {"_fields_": [
        (name, ctype if length is None else ctype * sizes[length])
        for name, ctype, length in MODEL_DATA[header_name]]})
    fields = [("state", ctypes.c_int), ("t0", ctypes.c_double), ("time", ctypes.c_double),
              ("real", ctypes.c_double * nvr), ("boolean", ctypes.c_int * nvr),
              ("integer", ctypes.c_int * nvr)]
    if nstring:
        fields.append(("string", (ctypes.c_char * STRING_MAX) * nstring))
    if defines.get("CLOCKED") == "1":  # an FMI 3.0 clocked build: the clock's schedule
        fields += [("tick_next", ctypes.c_long), ("clock_active", ctypes.c_int)]
    fields.append(("m", model))
    data = type("Data", (ctypes.Structure,), {"_fields_": fields})
    snapshot = type("Snapshot", (ctypes.Structure,), {"_fields_": [("h", Header),
                                                                    ("d", data)]})
    return Layout(defines, header_name, nx, nu, data, snapshot)


def decode(layout: Layout, blob: bytes) -> tuple[Any, list[float]]:
    """The Snapshot and the buffer of a serialized state (checked against the layout)."""
    snap = layout.snapshot.from_buffer_copy(blob[:layout.size])
    assert snap.h.data_size == ctypes.sizeof(layout.data), "the Data layout differs from C"
    assert len(blob) == layout.size + 8 * snap.h.nbuf, "the length differs from C"
    return snap, list(struct.unpack(f"={snap.h.nbuf}d", blob[layout.size:]))


def encode(snap: Any, buf: list[float]) -> bytes:
    """The serialized state of ``snap`` and ``buf``, ``h.nbuf`` set to the buffer's length
    (so that a mutation passes the length check and reaches the validation)."""
    snap.h.nbuf = len(buf)
    return bytes(snap) + struct.pack(f"={len(buf)}d", *buf)


@dataclass
class Leaf:
    """One field of a Snapshot: where it lies in the serialized state, its C type and its
    value there."""

    path: str
    offset: int
    ctype: Any
    value: Any

    def write(self, blob: bytearray, value) -> None:
        """Set the field to ``value`` in ``blob``; a char or byte array from bytes (zero
        padded, not terminated when they fill it)."""
        size = ctypes.sizeof(self.ctype)
        if issubclass(self.ctype, ctypes.Array):
            data = bytes(value)[:size].ljust(size, b"\0")
        else:
            data = bytes(self.ctype(value))
        blob[self.offset:self.offset + size] = data


def leaves(obj: Any, prefix: str = "", base: int | None = None) -> list[Leaf]:
    """Every field of a ctypes structure (offsets from ``obj``'s start), arrays of numbers
    element by element; a char array (a String value) and the header's magic and token
    as one field each."""
    base = ctypes.addressof(obj) if base is None else base
    out: list[Leaf] = []
    for name, ctype in obj._fields_:
        path, value = f"{prefix}{name}", getattr(obj, name)
        offset = ctypes.addressof(obj) - base + getattr(type(obj), name).offset
        if isinstance(value, ctypes.Structure):
            out += leaves(value, path + ".", base)
        elif isinstance(value, ctypes.Array) and ctype._type_ not in (ctypes.c_char,
                                                                      ctypes.c_ubyte):
            item = ctype._type_
            out += [Leaf(f"{path}[{k}]", offset + k * ctypes.sizeof(item), item,
                         bytes(value[k]) if issubclass(item, ctypes.Array) else value[k])
                    for k in range(len(value))]
        else:
            out.append(Leaf(path, offset, ctype,
                            bytes(value) if isinstance(value, ctypes.Array) else value))
    return out


def _values_for(leaf: Leaf, seen: dict[str, set]) -> list[Any]:
    """The boundary values tried for one field: its type's, its neighbours, and the values
    the same field has in the other states (another phase's sizes, positions, flags)."""
    value, ctype = leaf.value, leaf.ctype
    if leaf.path == "h.data_size":
        return [0, value - 1, value + 1, 2**64 - 1]
    if leaf.path in ("h.magic", "h.token"):
        return [bytes([value[0] ^ 1]) + value[1:]]
    if leaf.path == "d.state":
        return [0, *STATES.values(), 3, 32, -1]
    if issubclass(ctype, ctypes.Array):  # a String value
        return [*STRINGS, *sorted(seen.get(leaf.path, ()))]
    if ctype is ctypes.c_double:
        return [*DOUBLES, value * 2, -value, value + 1e-9 * abs(value),
                *sorted(seen.get(leaf.path, ()), key=repr)]
    extra = [value - 1, value + 1, *sorted(seen.get(leaf.path, ()))]
    if ctype is ctypes.c_long:
        return [v for v in (*LONGS, *extra) if LONG_MIN <= v <= LONG_MAX]
    return [v for v in (*INTS, *extra) if INT_MIN <= v <= INT_MAX]


def _buffer_mutations(buf: list[float], others: dict[str, list[float]]
                      ) -> Iterator[tuple[str, list[float]]]:
    yield "buffer dropped", []
    if buf:
        yield "buffer truncated by one", buf[:-1]
        yield "buffer halved", buf[: len(buf) // 2]
        yield "buffer doubled", buf + buf
        yield "buffer of NaN", [math.nan] * len(buf)
        yield "buffer of inf", [math.inf] * len(buf)
    yield "buffer extended by one", [*buf, 0.0]
    for phase, other in others.items():
        yield f"buffer of {phase}", other


def mutations(layout: Layout, states: dict[str, bytes], phase: str
              ) -> Iterator[tuple[str, bytes]]:
    """Structure-aware mutations of ``states[phase]``: (what, serialized state). Each field
    at each of its boundary values (the header's length kept right so that the mutation
    reaches the checks of the state), the buffer dropped, truncated, extended, filled with
    non-finite numbers or swapped with another phase's, and the data of this phase with the
    buffer of each other phase. Duplicates are left out."""
    decoded = {name: decode(layout, blob) for name, blob in states.items()}
    seen: dict[str, set] = {}
    for snap, _ in decoded.values():
        for leaf in leaves(snap):
            if leaf.path.startswith("d."):
                value = leaf.value
                seen.setdefault(leaf.path, set()).add(
                    value.rstrip(b"\0") if isinstance(value, bytes) else value)
    original = states[phase]
    done = {original}
    snap0, buf0 = decoded[phase]
    for leaf in leaves(snap0):
        for value in _values_for(leaf, seen):
            mutated = bytearray(original)
            leaf.write(mutated, value)
            if bytes(mutated) not in done:
                done.add(bytes(mutated))
                yield f"{leaf.path} = {value!r}", bytes(mutated)
    # the pairs: a phase or a flag of the model changed and the buffer dropped (a
    # state in 'step complete' without its buffer, a controller marked unbuilt that keeps
    # its history's sizes and positions)
    for leaf in leaves(snap0):
        if leaf.path == "d.state" or (leaf.path.startswith("d.m.") and leaf.ctype is ctypes.c_int):
            for value in STATES.values() if leaf.path == "d.state" else (0, 1):
                dropped = bytearray(encode(decode(layout, original)[0], []))
                leaf.write(dropped, value)
                if bytes(dropped) not in done:
                    done.add(bytes(dropped))
                    yield f"{leaf.path} = {value!r} and the buffer dropped", bytes(dropped)
    others = {name: buf for name, (_, buf) in decoded.items() if name != phase}
    for what, buf in _buffer_mutations(buf0, others):
        snap, _ = decode(layout, original)
        blob = encode(snap, buf)
        if blob not in done:
            done.add(blob)
            yield what, blob


# -- the child: the mutations of a batch of states against one instance -------------------
def run_batch(spec_path: Path) -> None:
    """Deserialize and set each mutation of each state of a batch (``spec_path``, JSON)
    into one instance of its FMU and write one JSON line per mutation to ``spec["out"]``,
    after a line naming the mutation it starts (so that a crash is traced to it): refused
    (the status, the messages logged, whether the instance was left as it was) or accepted
    (then its outputs are read, it takes a step from its own time and its state is saved:
    the statuses of the three calls). Between mutations the phase's own state is set."""
    from fmpy.fmi1 import FMICallException

    from delaycomp.orchestrator.fmu import FmuComponent

    spec = json.loads(spec_path.read_text(encoding="utf-8"))
    fmu = Path(spec["fmu"])
    layout = layout_of(fmu)
    states = {phase: bytes.fromhex(blob) for phase, blob in spec["states"].items()}
    comp = FmuComponent("fuzzed", fmu)
    comp.setup(0.0, 1e9, spec["parameters"])
    comp.initialize()
    assert comp.fmu is not None
    vrs = comp._vrs(comp.output_names)
    with open(spec["out"], "w", encoding="utf-8") as out:
        for phase, base in states.items():
            _restore(comp, base)
            baseline = comp.get_state()
            for what, blob in mutations(layout, states, phase):
                out.write(json.dumps({"start": f"{phase}: {what}"}) + "\n")
                out.flush()
                record = _try(comp, blob, FMICallException)
                if record["status"]:
                    record["unchanged"] = comp.get_state() == baseline
                else:
                    record["after"] = _exercise(comp, layout, vrs, spec["h"],
                                                FMICallException)
                    _restore(comp, base)
                out.write(json.dumps({"phase": phase, "what": what, **record}) + "\n")
                out.flush()
    comp.terminate()


def _restore(comp, blob: bytes) -> None:
    """Set a legitimate state (the statuses of the calls before forgotten)."""
    comp.worst_status = 0
    comp.call_failed = False
    comp.set_state(blob)


def _try(comp, blob: bytes, error: Any) -> dict:
    """Deserialize ``blob`` and set it: the status (0 when both succeed) and the messages."""
    assert comp.fmu is not None
    n_messages = len(comp.messages)
    status = 0
    try:
        state = comp.fmu.deSerializeFMUstate(blob)
        try:
            comp.fmu.setFMUstate(state)
        finally:
            comp.fmu.freeFMUstate(state)
    except error as exc:
        status = exc.status
    return {"status": status,
            "messages": [m.split("] ", 1)[-1] for m in comp.messages[n_messages:]]}


def _exercise(comp, layout: Layout, vrs: list[int], h: float, error: Any
              ) -> list[int]:
    """An accepted state at work: read the outputs, take a step of ``h`` from its own time,
    save the state again. The statuses of the three calls (0 ok .. 3 error)."""
    assert comp.fmu is not None
    fmu = comp.fmu
    snap, _ = decode(layout, comp.get_state())
    t = float(snap.d.time) if math.isfinite(snap.d.time) else 0.0
    statuses = []
    for call in (lambda: fmu.getReal(vrs),
                 lambda: fmu.doStep(currentCommunicationPoint=t, communicationStepSize=h),
                 comp.get_state):
        try:
            call()
            statuses.append(0)
        except error as exc:
            statuses.append(exc.status)
    return statuses


if __name__ == "__main__":
    run_batch(Path(sys.argv[1]))
