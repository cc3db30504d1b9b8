"""A loop file's network channels and time stamps: a ``[meas_delay]`` or ``[input_delay]``
table puts a network channel (``delaycomp.maths.channel.Channel``, the channel FMU) in that
delay's place (``channel_of``, ``with_channels``; a ``trace`` CSV read by ``read_trace``),
and ``[controller] stamps = true`` the time-stamp controller, its input ``stamp`` wired to
the measurement channel's (``with_stamps``).

The reader (``delaycomp.system.loopfile``) applies them to the loop it builds.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from delaycomp.errors import BadFileError, ParameterError
from delaycomp.system.loop import Instance, Loop
from delaycomp.system.loopkeys import CHANNEL_TABLES, allowed
from delaycomp.system.loopvalues import DECIMAL, check_keys, check_value, real_value

#: the longest delay trace a channel takes (``delaycomp.fmu.build.TRACE_MAX``, the channel
#: FMU's ``trace[1..L]``, which the tests hold it to)
TRACE_MAX = 10_000
_CHANNEL_NUMBERS = ("delay", "jitter", "shape", "max_delay", "loss", "p_gb", "p_bg",
                    "loss_good", "loss_bad", "period")
_CHANNEL_WORDS = ("distribution", "loss_model", "policy")


def read_trace(path: Path, where: str) -> tuple[float, ...]:
    """The delays [s] of a trace CSV: the column headed ``delay`` (else the first; a
    file whose first row is a number has no header), an empty cell or ``nan`` a lost
    packet (NaN); at most ``TRACE_MAX`` rows. ``where`` names the key in messages.

    Examples
    --------
    >>> import tempfile, pathlib
    >>> f = pathlib.Path(tempfile.mkdtemp()) / "trace.csv"
    >>> _ = f.write_text("time,delay\\n0,0.02\\n1,\\n2,nan\\n3,0.05\\n")
    >>> read_trace(f, "meas_delay.trace")
    (0.02, nan, nan, 0.05)
    """
    import csv

    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise BadFileError(path, f"no such file ({where})") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise BadFileError(path, f"cannot be read ({where}): {exc}") from None
    rows = [row for row in csv.reader(text.splitlines()) if any(c.strip() for c in row)]
    if not rows:
        raise ParameterError(f"{where} = {path.name!r} is not allowed: the file holds no "
                             "delays")
    column, first = 0, rows[0]
    if not DECIMAL.match(first[0].strip()) and first[0].strip().lower() != "nan":
        names = [c.strip() for c in first]
        column = names.index("delay") if "delay" in names else 0
        rows = rows[1:]
    if not 1 <= len(rows) <= TRACE_MAX:
        raise ParameterError(f"{where} = {path.name!r} ({len(rows)} delays) is not allowed: "
                             f"must hold 1 to {TRACE_MAX} delays")
    delays = []
    for i, row in enumerate(rows):
        cell = row[column].strip() if column < len(row) else ""
        if cell == "" or cell.lower() == "nan":
            delays.append(math.nan)
            continue
        if not DECIMAL.match(cell) or float(cell) < 0:
            raise ParameterError(f"{where} = {path.name!r}: delay {i + 1} ({cell!r}) is not "
                                 "allowed: must be a finite number >= 0 [s], or empty or nan "
                                 "(a lost packet)")
        delays.append(float(cell))
    return tuple(delays)


def channel_of(table: dict, name: str, base: Path, true_delay: float, where: str = "loop"):
    """The ``delaycomp.maths.channel.Channel`` of a loop file's channel table ``name``
    (``[meas_delay]`` or ``[input_delay]``): its keys and values checked, each refusal one
    line naming ``name.key`` and what is allowed; ``delay`` defaults to the loop's true
    delay ``true_delay`` (with a trace, to the trace's smallest delay).

    Examples
    --------
    >>> from pathlib import Path
    >>> channel_of({"distribution": "uniform", "jitter": 0.05}, "meas_delay", Path("."),
    ...            0.1).bound()
    0.15000000000000002
    >>> channel_of({"loss": 2}, "input_delay", Path("."), 0.0)  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ...
    delaycomp.errors.ParameterError: input_delay.loss = 2.0 is not allowed: must be a ...
    """
    from delaycomp.maths.channel import Channel

    if not isinstance(table, dict):
        raise ParameterError(f"{where}: {name} must be a table ([{name}])")
    check_keys(f"{where} [{name}]", table, allowed("channel", "lti"))
    values: dict[str, Any] = {}
    for key in _CHANNEL_NUMBERS:
        if key in table:
            values[key] = real_value(f"{name}.{key}", table[key])
    for key in _CHANNEL_WORDS:
        if key in table:
            if not isinstance(table[key], str):
                raise ParameterError(f"{name}.{key} = {table[key]!r} is not allowed: must be "
                                     "a string")
            values[key] = table[key]
    if "seed" in table:
        seed = table["seed"]
        if isinstance(seed, float) and seed.is_integer():  # --set seed=3 reads 3.0
            seed = int(seed)
        values["seed"] = seed
    if "trace" in table:
        given = table["trace"]
        if isinstance(given, (list, tuple)):  # the delays themselves (the API's Channel)
            trace = tuple(real_value(f"{name}.trace[{i + 1}]", d) if not (
                isinstance(d, float) and math.isnan(d)) else math.nan
                for i, d in enumerate(given))
        elif isinstance(given, str):
            path = Path(given)
            trace = read_trace(path if path.is_absolute() else base / path, f"{name}.trace")
        else:
            raise ParameterError(f"{name}.trace = {given!r} is not allowed: must be a CSV "
                                 "file's path")
        values["trace"] = trace
        if values.get("distribution", "constant") == "trace" and "delay" not in values:
            finite = [d for d in trace if not math.isnan(d)]
            values["delay"] = min(finite) if finite else true_delay
    values.setdefault("delay", float(true_delay))
    channel = Channel(**values)
    try:
        channel.check()
    except ValueError as exc:
        raise ParameterError(f"{name}.{exc}") from None
    if channel.distribution == "trace" and not channel.trace:
        raise ParameterError(f"{name}.trace is required for distribution = 'trace': a CSV "
                             "file of measured delays")
    return channel


def channel_parameters(channel, u0_params: dict) -> dict:
    """The channel FMU's parameter values (``fmus/delay/README.md``) of ``channel``, with
    the delay's input history ``u0[i]`` (``u0_params``)."""
    params: dict[str, Any] = {
        "delay": channel.delay, "distribution": channel.distribution,
        "jitter": channel.jitter, "shape": channel.shape,
        "max_delay": 0.0 if channel.max_delay is None else channel.max_delay,
        "loss_model": channel.loss_model, "loss": channel.loss, "p_gb": channel.p_gb,
        "p_bg": channel.p_bg, "loss_good": channel.loss_good, "loss_bad": channel.loss_bad,
        "policy": channel.policy, "seed": channel.seed, "period": channel.period}
    for i, d in enumerate(channel.trace):
        params[f"trace[{i + 1}]"] = -1.0 if math.isnan(d) else d
    return {**params, **u0_params}


def with_channels(loop: Loop, data: dict, base: Path, where: str = "loop") -> Loop:
    """``loop`` with a network channel in the place of each delay whose role names a table
    of ``data`` (``[meas_delay]``, ``[input_delay]``): the instance becomes the channel
    FMU (``BuiltinFmu("channel", {"n": n, "L": L})``, ``L`` the trace's length, none
    without a trace: the registry's default build) with the
    table's channel and the delay's input history; without those tables, ``loop`` as it
    is."""
    from delaycomp.system.loop import BuiltinFmu

    tables = [t for t in CHANNEL_TABLES if t in data]
    if not tables:
        return loop
    instances = []
    for inst in loop.instances:
        if inst.role not in tables:
            instances.append(inst)
            continue
        src = inst.source
        if not (isinstance(src, BuiltinFmu) and src.kind == "delay"):
            raise ParameterError(f"{where}: [{inst.role}] is not allowed: the loop's "
                                 f"{inst.role} is not delaycomp's delay FMU")
        channel = channel_of(data[inst.role], inst.role, base, float(inst.parameters["delay"]),
                             where)
        u0 = {k: v for k, v in inst.parameters.items() if k.startswith("u0[")}
        config = {"n": int(src.config["n"])}
        if channel.trace:  # the default build (and its file) where there is no trace
            config["L"] = len(channel.trace)
        instances.append(Instance(inst.name, inst.role, BuiltinFmu("channel", config),
                                  channel_parameters(channel, u0)))
    return loop.with_instances(instances)


def refuse_channel_data(data: dict, what: str, where: str = "loop") -> None:
    """``refuse_channel`` for loop-file ``data`` (before a loop is built)."""
    for table in CHANNEL_TABLES:
        if table in data:
            raise ParameterError(f"{where}: the [{table}] channel is not supported by {what} "
                                 "yet")


def _channel_from(params: Mapping[str, Any]):
    """The ``Channel`` of a channel instance's parameters (``channel_parameters`` read
    back)."""
    from delaycomp.maths.channel import Channel

    trace = tuple(math.nan if v < 0 else v for k, v in sorted(
        ((k, v) for k, v in params.items() if k.startswith("trace[")),
        key=lambda kv: int(kv[0][6:-1])))
    names = ("delay", "distribution", "jitter", "shape", "loss_model", "loss", "p_gb", "p_bg",
             "loss_good", "loss_bad", "policy", "seed", "period")
    return Channel(**{k: params[k] for k in names}, trace=trace,
                   max_delay=params["max_delay"] or None)


def with_stamps(loop: Loop, data: dict, where: str = "loop") -> Loop:
    """``loop`` with the time-stamp controller where ``[controller] stamps = true``: an
    LTI loop's controller becomes ``BuiltinFmu("stamped_controller", ...)`` (parameters
    ``T``, ``tau``, ``age_max``, ``mode``, ``A``, ``B``, ``K``, ``u0``), a model loop's
    zero-order-hold controller ``ModelFmu("stamped_model_controller", model)`` (``T``,
    ``tau``, ``age_max``, ``mode``, ``tolerance``, ``u0``, the model's parameters); its
    input ``stamp`` connected to the measurement channel's (a constant channel in the
    place of a plain measurement delay); otherwise ``loop`` as it is."""
    from delaycomp.system.loop import BuiltinFmu, Connection, ModelFmu, Port

    ctrl_data = data.get("controller") or {}
    if not check_value("controller.stamps", ctrl_data.get("stamps", False),
                       f"{where}: controller.stamps"):
        if "age_max" in ctrl_data:
            raise ParameterError(f"{where}: controller.age_max is not allowed without "
                                 "controller.stamps = true")
        return loop
    ctrl, meas = loop.by_role("controller"), loop.by_role("meas_delay")
    model = (ctrl.source.model if ctrl is not None and isinstance(ctrl.source, ModelFmu)
             and ctrl.source.kind == "model_controller" else None)
    if not (ctrl is not None and meas is not None
            and (model is not None or (isinstance(ctrl.source, BuiltinFmu)
                                       and ctrl.source.kind == "controller"))
            and isinstance(meas.source, BuiltinFmu)
            and meas.source.kind in ("delay", "channel")):
        raise ParameterError(f"{where}: controller.stamps = true is not allowed for this "
                             "loop: the time-stamp controller is an LTI loop's ([plant] A, B) "
                             "or a zero-order-hold model loop's ([plant] model)")
    if model is not None:
        check_stamped_model(model, where)
    if meas.source.kind == "delay":  # a constant channel: the same numbers, and a stamp
        from delaycomp.maths.channel import Channel

        u0 = {k: v for k, v in meas.parameters.items() if k.startswith("u0[")}
        meas = Instance(meas.name, meas.role,
                        BuiltinFmu("channel", {"n": int(meas.source.config["n"])}),
                        channel_parameters(Channel(delay=float(meas.parameters["delay"])),
                                           u0))
    T = float(ctrl.parameters["T"])
    age_max = ctrl_data.get("age_max")
    age_max = (_channel_from(meas.parameters).bound() + T if age_max is None
               else check_value("controller.age_max", age_max, f"{where}: controller.age_max"))
    source: BuiltinFmu | ModelFmu
    if model is None:
        assert isinstance(ctrl.source, BuiltinFmu)  # checked above
        # pad: the time-stamp controller predicts over any tau, as the model branch's
        params = {k: v for k, v in ctrl.parameters.items() if k not in ("r", "pad")}
        source = BuiltinFmu("stamped_controller", dict(ctrl.source.config))
    else:  # the model controller's settings that the time-stamp controller has
        params = {k: v for k, v in ctrl.parameters.items()
                  if k not in ("r", "N", "pad", "predictor", "mode") and not k.startswith("z0[")}
        params["mode"] = ("uncompensated" if ctrl.parameters.get("predictor") == "none"
                          else "compensated")
        source = ModelFmu("stamped_model_controller", model)
    params["age_max"] = float(age_max)
    stamped = Instance(ctrl.name, ctrl.role, source, params)
    instances = [stamped if i.name == ctrl.name else meas if i.name == meas.name else i
                 for i in loop.instances]
    wire = Connection(Port(meas.name, "stamp"), Port(ctrl.name, "stamp"))
    return loop.replace(instances=tuple(instances), connections=(*loop.connections, wire))


def check_stamped_model(model_path, where: str) -> None:
    """A model loop's time-stamp controller holds ``k(x, p)`` over each period: a model
    whose ``CONTROL`` is not ``"zoh"`` is refused in one line naming ``controller.stamps``."""
    from delaycomp.maths.model import load_model

    model = load_model(model_path)
    if model.control != "zoh":
        raise ParameterError(f"{where}: controller.stamps = true is not allowed for model "
                             f"{model.name!r}: its CONTROL is {model.control!r}; the time-stamp "
                             "controller holds k(x, p) over each period (CONTROL = 'zoh')")
