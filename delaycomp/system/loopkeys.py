"""The keys of a loop file: which loop takes each, whether it is required, its default.

One table, ``TABLE``, read by the loop-file reader (``delaycomp.system.loopfile``:
the keys each table allows, ``DEFAULTS``) and by the documentation build (the
reference page's tables are ``markdown``), so the page says what the reader does;
``tests/test_loop_keys.py`` holds the reader to it (a required key left out is refused
naming it; a default written out builds the same loop as the key left out).

A loop is one of five kinds, by its plant and, for a plant FMU, by where the predictor's
model comes from: ``lti`` (``[plant] A, B``), ``model`` (``[plant] model``), and around a
plant FMU (``[plant] fmu``) ``fmu-lti`` (``[controller] A, B, K``), ``fmu-model``
(``[controller] model``), ``fmu-plant-fmu`` (``[controller] predictor = "plant-fmu"``).

Examples
--------
>>> allowed("plant", "lti")
('A', 'B', 'x0', 'state', 'input')
>>> [e.key for e in TABLE if e.table == "" and e.required]
['T']
>>> DEFAULTS["N"], DEFAULTS["controller.mode"]
(100, 'compensated')
"""

from __future__ import annotations

from dataclasses import dataclass

from delaycomp.names import MODES

#: the kinds of loop (module docstring)
KINDS = ("lti", "model", "fmu-lti", "fmu-model", "fmu-plant-fmu")
ALL = KINDS
FMU = ("fmu-lti", "fmu-model", "fmu-plant-fmu")
#: the kinds whose controller is a model file's (its own parameters are keys too)
MODEL_CONTROLLERS = ("model", "fmu-model")

#: the ODE tolerance of the numerical predictors and of a model plant without an exact
#: step (``delaycomp.maths.predictors.DEFAULT_TOL``, which the tests hold it to)
ODE_TOL = 1e-10


@dataclass(frozen=True)
class Entry:
    """One key of one table for some kinds of loop.

    ``default`` is the value the reader takes when the key is left out (a Python value,
    written out it builds the same loop), ``None`` where the default is not a value of the
    key (``shown`` says what it is in words), ``required`` where it must be given."""

    table: str              # "" (top level), "plant", "controller", "channel", "reference"
    key: str
    kinds: tuple[str, ...]
    meaning: str
    required: bool = False
    default: object = None
    shown: str = ""         # the default in words, where it is not ``default``
    allowed: str = ""       # the values allowed in words, where the reader's KEYS do not say

    def default_text(self) -> str:
        """The default as the reference page shows it."""
        if self.required:
            return "required"
        if self.shown:
            return self.shown
        if isinstance(self.default, bool):
            return "`" + str(self.default).lower() + "`"
        if isinstance(self.default, str):
            return f'`"{self.default}"`'
        return f"`{self.default!r}`"


E = Entry
#: every key of a loop file, in the order the reference page shows them
TABLE: tuple[Entry, ...] = (
    E("", "T", ALL, "sampling period [s]: the controller samples at `t_i = t0 + i T`",
      required=True),
    E("", "N", ALL, "base steps per period: the master's step is `h = T/N`", default=100),
    E("", "r", ALL, "measurement delay the controller assumes [s], a multiple of `h`",
      default=0.0),
    E("", "tau", ALL, "input delay the controller assumes [s], a multiple of `h`; under "
      "zero-order hold a multiple of `T` (Theorem 3.2) unless `pad`", default=0.0),
    E("", "r_true", ALL, "the loop's true measurement delay (the delay FMU's), for mismatch "
      "studies", shown="`r`"),
    E("", "tau_true", ALL, "the loop's true input delay", shown="`tau`"),
    E("", "stop_time", ALL, "the stop time of `run` [s]", shown="none: `run` then needs "
      "`--stop-time`"),
    E("", "name", ALL, "the loop's name: file names, the figure's title", shown="the file's "
      "stem"),
    E("", "title", ALL, "one line saying what the loop is: the figure's title",
      shown="`loop file NAME.toml`"),
    # [plant]
    E("plant", "A", ("lti",), "an LTI plant `x' = A x + B u` (`n x n`)", required=True),
    E("plant", "B", ("lti",), "its input matrix (`n x m`)", required=True),
    E("plant", "model", ("model",), "a model file (`\"file.py\"`, relative to the loop "
      "file's folder)", required=True),
    E("plant", "fmu", FMU, "an FMU file of another tool (FMI 2.0 co-simulation), relative "
      "to the loop file's folder", required=True),
    E("plant", "states", FMU, "the FMU outputs that form the measured `x`, in order",
      required=True),
    E("plant", "inputs", FMU, "the FMU inputs that receive `u`, in order", required=True),
    E("plant", "x0", ALL, "the constant history of `x` on `[-r, 0]` (`n` numbers); a plant "
      "FMU must start there (checked)", required=True),
    E("plant", "state", ("lti",), "base name of the state columns (`plant.x1`, ...)",
      default="x"),
    E("plant", "input", ("lti",), "base name of the input columns (`controller.u1`, ...)",
      default="u"),
    E("plant", "parameters", FMU, "values of the FMU's parameters by its own names, set "
      "before initialization", shown="none"),
    E("plant", "start", FMU, "start values of its other settable variables (`initial = "
      "\"exact\"` states, undriven inputs)", shown="none (with `predictor = \"plant-fmu\"`: "
      "found from `x0`)"),
    E("plant", "tolerance", ("model", *FMU), "a model plant's ODE tolerance (without an "
      "exact `step`); a plant FMU's `fmi2SetupExperiment` tolerance, in (0, 1)",
      shown=f"`{ODE_TOL:g}` (model); the FMU's own (FMU)"),
    # [controller]
    E("controller", "A", ("fmu-lti",), "the predictor's LTI model of the plant FMU, in the "
      "measured coordinates", required=True),
    E("controller", "B", ("fmu-lti",), "its input matrix", required=True),
    E("controller", "model", ("fmu-model",), "the predictor's model file", required=True),
    E("controller", "predictor", ("fmu-plant-fmu",), "`\"plant-fmu\"`: the plant FMU's own "
      "Model Exchange derivatives as the predictor's model", required=True,
      allowed="plant-fmu"),
    E("controller", "predictor", MODEL_CONTROLLERS, "`\"closed\"` (the model's closed form "
      "or exact `step`) or `\"numerical\"` (an ODE solve over the stored inputs)",
      shown="`\"closed\"` where the model has a closed form, else `\"numerical\"`"),
    E("controller", "K", ("lti", "fmu-lti", "fmu-plant-fmu"), "the gain, `u = K x` (the "
      "paper's sign; python-control's `lqr` gives `-K`)", required=True),
    E("controller", "mode", ALL, "`\"compensated\"` (the predictor) or `\"uncompensated\"` "
      "(the feedback on the sample itself)", default="compensated"),
    E("controller", "u0", ALL, "the constant input history on `[-r - tau, 0)` (`m` numbers)",
      shown="zeros"),
    E("controller", "stamps", ("lti", "model"), "`true`: the time-stamp controller: "
      "the predictor integrates over each sample's actual age, the measurement "
      "channel's `stamp`, plus `tau`; a lost sample means predicting from the last one "
      "received (`[meas_delay]` becomes a constant channel where it is no table); a model "
      "loop's model must have `CONTROL = \"zoh\"`", default=False),
    E("controller", "age_max", ("lti", "model"), "with `stamps`: the largest age [s] of a "
      "sample the predictor uses (an older one is not); it sizes the stored inputs",
      shown="the measurement channel's largest delay + `T`"),
    E("controller", "allow_unstable", ("lti", "model", "fmu-lti"), "let through an LTI `K` "
      "with which the delay-free sampled loop is unstable (the sign guard)", default=False),
    E("controller", "pad", (*MODEL_CONTROLLERS, "lti", "fmu-lti"), "accept a `tau` that is not a "
      "multiple of `T` under zero-order hold: the controller delays its output to the next "
      "multiple (Remark 3.3(b))", default=False),
    E("controller", "tolerance", (*MODEL_CONTROLLERS, "fmu-plant-fmu"), "the numerical "
      "predictor's ODE tolerance (rtol = atol), in (0, 1)", shown=f"`{ODE_TOL:g}` (model: "
      "`[plant] tolerance` where given)"),
    E("controller", "(any other key)", MODEL_CONTROLLERS, "a model parameter, by its name "
      "in the module's `PARAMETERS`", shown="the model's value"),
    # [meas_delay], [input_delay]: a network channel in the delay's place
    E("channel", "distribution", ALL, "the delay's random part: `\"constant\"` (none), "
      "`\"uniform\"` on `[0, jitter)`, `\"exponential\"` of mean `jitter`, `\"gamma\"` of mean "
      "`jitter` and shape `shape`, or `\"trace\"` (the delays of `trace`, replayed in order "
      "from an offset drawn from the seed)", shown='`"constant"`'),
    E("channel", "delay", ALL, "the least delay [s]: every packet's delay is `delay` plus "
      "the draw", shown="`r_true` (`[meas_delay]`), `tau_true` (`[input_delay]`); with a "
      "trace, its smallest delay"),
    E("channel", "jitter", ALL, "the random part's scale [s]: uniform's width, "
      "exponential's and gamma's mean", shown="`0.0`"),
    E("channel", "shape", ALL, "gamma's shape", shown="`1.0`"),
    E("channel", "trace", ALL, "a CSV file of measured delays (relative to the loop file's "
      "folder): one column in seconds, headed `delay` (else the first column); an empty "
      "cell or `nan` is a lost packet", shown="none", allowed="a CSV file of 1 to 10000 "
      "delays"),
    E("channel", "max_delay", ALL, "the timeout [s]: a packet later than this is lost",
      shown="the distribution's largest delay (required for exponential and gamma with "
      "jitter)"),
    E("channel", "loss_model", ALL, "`\"none\"`, `\"bernoulli\"` (`loss`) or "
      "`\"gilbert_elliott\"` (a good/bad chain: `p_gb`, `p_bg`, `loss_good`, `loss_bad`)",
      shown='`"none"`'),
    E("channel", "loss", ALL, "bernoulli: the probability that a packet is lost",
      shown="`0.0`"),
    E("channel", "p_gb", ALL, "gilbert_elliott: probability of going from good to bad",
      shown="`0.0`"),
    E("channel", "p_bg", ALL, "gilbert_elliott: probability of going from bad to good",
      shown="`1.0`"),
    E("channel", "loss_good", ALL, "gilbert_elliott: loss probability in the good state",
      shown="`0.0`"),
    E("channel", "loss_bad", ALL, "gilbert_elliott: loss probability in the bad state",
      shown="`1.0`"),
    E("channel", "policy", ALL, "`\"in_order\"` (a packet waits for those sent before it), "
      "`\"drop_stale\"` (a packet older than the one shown is dropped) or `\"playout\"` (a "
      "play-out buffer: each packet shown at its send time + `max_delay`, a constant delay)",
      shown='`"in_order"`'),
    E("channel", "seed", ALL, "the draws' seed: the same seed, the same packets' fates",
      shown="`0`"),
    E("channel", "period", ALL, "time between packets [s], a multiple of `h`; 0: every "
      "base step", shown="`0.0`"),
    # [reference]
    E("reference", "csv", ALL, "a reference trace for `delaycomp check LOOP.toml`: `time`, "
      "then columns named as the run's", required=True),
    E("reference", "tolerance", ALL, "`|error| <= tolerance (1 + |ref|)`", default=1e-9),
)
del E

#: the tables a loop file may hold (``[reference]`` describes something besides the loop)
TABLES = ("plant", "controller", "meas_delay", "input_delay", "reference")
#: the tables of a network channel in a delay's place, each named by the role of
#: the delay it replaces; their keys are the ``"channel"`` entries of ``TABLE`` (no entry
#: has a ``default``: a key written out makes the table, and the table the channel, so
#: their defaults are in words, the channel's, ``delaycomp.maths.channel.Channel``)
CHANNEL_TABLES = ("meas_delay", "input_delay")


def allowed(table: str, kind: str) -> tuple[str, ...]:
    """The keys ``table`` allows in a loop of ``kind``, in the table's order (a model
    controller's own parameters besides).

    Examples
    --------
    >>> allowed("controller", "fmu-plant-fmu")
    ('predictor', 'K', 'mode', 'u0', 'tolerance')
    """
    keys: list[str] = []
    for e in TABLE:
        if e.table == table and kind in e.kinds and e.key not in keys \
                and not e.key.startswith("("):
            keys.append(e.key)
    return tuple(keys)


def required(table: str, kind: str) -> tuple[str, ...]:
    """The keys ``table`` requires in a loop of ``kind``."""
    return tuple(e.key for e in TABLE if e.table == table and kind in e.kinds and e.required)


#: the model predictors a loop file names (``[controller] predictor``)
PREDICTORS = ("closed", "numerical")
#: the allowed range of a delay on the base grid (``r``, ``r_true``, ``tau_true``, and
#: ``tau`` under continuous input), as ``delaycomp list`` and docs/reference/commands.md say it
ON_BASE_GRID = "a finite number >= 0, a whole number of base steps h = T/N"
#: ``tau`` under zero-order hold (Theorem 3.2); ``ZOH_TAU_PAD`` where ``pad`` is offered
ZOH_TAU = "a finite multiple l*T of T, l >= 0"
ZOH_TAU_PAD = f"{ZOH_TAU} (with pad=1: {ON_BASE_GRID})"

#: the values allowed, in words, of each key the reader checks on its own, by dotted name:
#: the reader's ``KEYS`` (``delaycomp.system.loopvalues``) pair each with its check, and
#: ``delaycomp list`` prints them without importing the reader (and so numpy)
ALLOWED: dict[str, str] = {
    "T": "a finite number > 0",
    "N": "a positive integer",
    **dict.fromkeys(("r", "tau", "r_true", "tau_true"), ON_BASE_GRID),
    "stop_time": "a finite number > 0",
    "plant.A": "rows of finite numbers",
    "plant.B": "rows of finite numbers",
    "plant.x0": "comma-separated finite numbers",
    "controller.K": "rows of finite numbers",
    "controller.u0": "comma-separated finite numbers",
    "controller.mode": " or ".join(MODES),
    "controller.predictor": " or ".join(PREDICTORS),
    "controller.pad": "true or false",
    "controller.allow_unstable": "true or false",
    "controller.stamps": "true or false",
    "controller.age_max": "a finite number >= 0 [s]",
}

#: the defaults that are values of their key, by dotted name (``"N"``,
#: ``"controller.mode"``): what the reader takes for a key left out
DEFAULTS: dict[str, object] = {
    (f"{e.table}.{e.key}" if e.table else e.key): e.default
    for e in TABLE if not e.required and e.default is not None
}

_KIND_WORDS = {"lti": "LTI", "model": "model", "fmu-lti": "FMU + LTI",
               "fmu-model": "FMU + model", "fmu-plant-fmu": "FMU + plant-fmu"}


def _kinds_text(kinds: tuple[str, ...]) -> str:
    if set(kinds) == set(KINDS):
        return "all"
    words = [_KIND_WORDS[k] for k in kinds if k not in FMU]
    if set(FMU) <= set(kinds):
        words.append("FMU")
    else:
        words += [_KIND_WORDS[k] for k in kinds if k in FMU]
    return ", ".join(words)


def markdown(allowed_words: dict[str, str] | None = None) -> str:
    """The reference page's tables of every key, one per table of the file: key, the
    loops that take it, required or its default, the values allowed, the meaning.
    ``allowed_words`` gives the allowed values in words by dotted key (the reader's
    ``KEYS``)."""
    words = allowed_words or {}
    titles = {"": "Top level", "plant": "`[plant]`", "controller": "`[controller]`",
              "channel": "`[meas_delay]` and `[input_delay]` (a network channel in the "
                         "delay's place)",
              "reference": "`[reference]` (for `delaycomp check LOOP.toml`)"}
    parts = []
    for table, title in titles.items():
        parts += [f"### {title}", "", "| key | loops | required / default | allowed | meaning |",
                  "|---|---|---|---|---|"]
        for e in TABLE:
            if e.table != table:
                continue
            dotted = f"{table}.{e.key}" if table else e.key
            key = e.key if e.key.startswith("(") else f"`{e.key}`"
            parts.append(f"| {key} | {_kinds_text(e.kinds)} | {e.default_text()} | "
                         f"{e.allowed or words.get(dotted, '')} | {e.meaning} |")
        parts.append("")
    return "\n".join(parts)
