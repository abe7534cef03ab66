"""A model file's ``manifest.json`` as a dataclass that checks itself: export builds one, the recogniser and
`info` read one. Reading checks every field (its type, its range, the names this mlnseq runs) and the fields
against each other; a malformed one is refused in one line naming it (docs/model-file.md)."""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field, fields
from enum import Enum
from typing import Any, NoReturn

from mlnseq import networks
from mlnseq.catalog.decoders import Decoder, Decoding
from mlnseq.catalog.errors import BadInput
from mlnseq.catalog.methods import NETWORKS, MLNMode, Method, PaperFloor, Prior, WeightSource, network_of
from mlnseq.timeline.sequences import MODES

MODEL_FORMAT = 3  # 3: the paper floor of the MLN's sums; 2: members' sizes and digests, the number of formulas
MANIFEST, SPEC, WEIGHTS, NETWORK = "manifest.json", "binarize.toml", "weights.parquet", "network.npz"
AUDIT = "audit.json"  # what `mlnseq audit` learned from the labelled recordings (stages/auditing/profile.py)
AGAIN = "export the model again with `mlnseq export`"
NETWORK_SIZE_LIMIT, RECEPTIVE_FIELD_LIMIT = 4096, 2**16  # bound a network's arrays and its streaming state
MAX_LEVELS = 16  # a TCN's dilated levels: 2**16 frames of dilation at most
KIND_WORDS = {"int": "an integer", "float": "a number >= 0", "bool": "true or false", "str": "a string"}
FIGURES = ("segment_accuracy", "frame_accuracy", "edit", "f1_50")  # cross-validated figures (cross_validation)


def _integer(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _number(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


@dataclass(frozen=True)
class Fields:
    """Reads the fields of one JSON object of a manifest, refusing in one line what is absent or malformed."""

    values: Any
    where: Any
    what: str = MANIFEST

    def __post_init__(self) -> None:
        if not isinstance(self.values, dict):
            self.refuse(f"{self.what} is not an object")

    def refuse(self, text: str) -> NoReturn:
        raise BadInput(f"{self.where}: {text}: {AGAIN}")

    def get(self, key: str) -> Any:
        if key not in self.values:
            self.refuse(f"{self.what} lacks {key!r}")
        return self.values[key]

    def check(self, key: str, ok: bool, expected: str) -> Any:
        if not ok:
            self.refuse(f"{self.what} {key!r} is not {expected}")
        return self.values[key]

    def text(self, key: str) -> str:
        return self.check(key, isinstance(self.get(key), str), "a string")

    def integer(self, key: str) -> int:
        return self.check(key, _integer(self.get(key)), "an integer")

    def count(self, key: str) -> int:
        value = self.get(key)
        return self.check(key, _integer(value) and value >= 0, "a count")

    def number(self, key: str, low: float, high: float, optional: bool = False, nan: bool = False) -> float | None:
        """A finite number from ``low`` to ``high`` (or NaN, or null, where allowed)."""
        value = self.get(key)
        if value is None and optional:
            return None
        ok = _number(value) and ((math.isfinite(value) and low <= value <= high) or (nan and math.isnan(value)))
        return self.check(key, ok, f"{'null or ' if optional else ''}a finite number from {low:g} to {high:g}")

    def choice(self, key: str, allowed: tuple[str, ...] | type[Enum], optional: bool = False) -> Any:
        """A name among ``allowed`` (an enum's member when ``allowed`` is one)."""
        value = self.get(key)
        if value is None and optional:
            return None
        names = tuple(str(a) for a in allowed)
        if not isinstance(value, str) or value not in names:
            self.refuse(f"its {self.what} {key} {value!r} is not one this mlnseq runs ({', '.join(names)})")
        return allowed(value) if isinstance(allowed, type) else value

    def names(self, key: str, empty: bool, unique: bool = True) -> list[str]:
        value = self.get(key)
        ok = (isinstance(value, list) and all(isinstance(x, str) for x in value) and bool(empty or value)
              and (not unique or len(set(value)) == len(value)))
        return self.check(key, ok, f"a list of {'unique ' if unique else ''}strings{'' if empty else ', not empty'}")

    def mapping(self, key: str, valid: Any, expected: str) -> dict[str, Any]:
        value = self.get(key)
        ok = isinstance(value, dict) and all(isinstance(k, str) and valid(v) for k, v in value.items())
        return self.check(key, ok, expected)


def _scalar(value: Any) -> bool:
    return value is None or isinstance(value, (str, bool, int, float))


def _option(value: Any) -> bool:
    """A reading option's value: a JSON scalar or a list of them."""
    return _scalar(value) or (isinstance(value, list) and all(map(_scalar, value)))


def _text(value: Any) -> bool:
    return isinstance(value, str)


def _figures(value: Any) -> bool:
    """Cross-validated figures: at least FIGURES (conflate adds the log-likelihood, forbidden transitions)."""
    return (isinstance(value, dict) and set(FIGURES) <= set(value)
            and all(_number(v) or (v is None and k not in FIGURES) for k, v in value.items()))


def _member(value: Any) -> bool:
    return (isinstance(value, dict) and set(value) == {"bytes", "sha256"} and _integer(value["bytes"])
            and value["bytes"] >= 0 and isinstance(value["sha256"], str))


def _optional_count(read: Fields, key: str) -> int | None:
    """A count or null, None where absent (files written before the key)."""
    return None if read.values.get(key) is None else read.count(key)


@dataclass(frozen=True)
class Timing:
    """A model's decoder and its lag, the lag in seconds, the recordings' rate and the chains' start distribution
    (log-probabilities per class). Absent in older files: their filter or viterbi, no start distribution."""

    decoding: Decoding
    latency_s: float | None
    rate_hz: float | None
    start: list[float] | None

    @classmethod
    def read(cls, values: dict[str, Any], where: Any, n_classes: int) -> Timing:
        refuse = Fields({}, where).refuse
        decode, lag = values.get("decode"), values.get("lag")
        try:
            decoder = Decoder(decode)
        except ValueError:
            refuse(f"its manifest's decoder {decode!r} is not one this mlnseq runs "
                   f"({', '.join(d.value for d in Decoder)})")
        if lag is not None and not _integer(lag):
            refuse(f"its manifest's lag {lag!r} is not a whole number of frames")
        try:
            decoding = Decoding(decoder, lag)
        except BadInput as error:
            refuse(f"its manifest's {error}")
        numbers = {k: values.get(k) for k in ("latency_s", "rate_hz")}
        for key, value in numbers.items():
            if value is not None and not (_number(value) and math.isfinite(value) and value >= 0):
                refuse(f"its manifest's {key} {value!r} is not null or a number >= 0")
        start = values.get("start")
        if start is not None and not (isinstance(start, list) and len(start) == n_classes
                                      and all(_number(v) and math.isfinite(v) for v in start)):
            refuse(f"its manifest's start is not a list of {n_classes} finite log-probabilities")
        return cls(decoding, numbers["latency_s"], numbers["rate_hz"], start)


@dataclass(frozen=True)
class Chosen:
    """``export --method auto``: the decoded method chosen by cross-validation, its figures and the others'."""

    method: Method
    name: str
    figures: dict[str, float]
    score: float
    candidates: dict[str, dict[str, float]]
    folds: int
    budget_frames: int | None = None  # export --lag/--latency: the budget the candidates fitted

    @classmethod
    def read(cls, values: Any, where: Any) -> Chosen:
        read = Fields(values, where, f"{MANIFEST} chosen_by_cross_validation")
        chosen = cls(read.choice("method", Method), read.text("name"),
                     read.check("figures", _figures(read.get("figures")), f"an object of {', '.join(FIGURES)}"),
                     read.number("score", -math.inf, math.inf, nan=True),
                     read.mapping("candidates", _figures, "an object of method name -> figures"),
                     read.count("folds"), _optional_count(read, "budget_frames"))
        read.check("name", chosen.name in chosen.candidates, "one of its candidates")
        return chosen


@dataclass(frozen=True)
class NetworkEntry:
    """The manifest's network: which of the method's networks, how it was trained, its configuration (the keys
    of its type's Config, stages/networks/)."""

    name: Method
    mode: str
    prior: Prior | None
    seed: int
    kept_epoch: int
    model: dict[str, Any]

    @classmethod
    def read(cls, values: Any, where: Any) -> NetworkEntry:
        read = Fields(values, where, f"{MANIFEST} network")
        name = read.text("name")
        if name not in NETWORKS:
            read.refuse(f"its manifest's network {name!r} is not one this mlnseq runs ({', '.join(NETWORKS)})")
        model = read.get("model")
        read.check("model", isinstance(model, dict) and isinstance(model.get("cell"), str), "an object naming its cell")
        entry = cls(Method(name), read.choice("mode", MODES), read.choice("prior", Prior, optional=True),
                    read.integer("seed"), read.count("kept_epoch"), model)
        entry.check_model(where)
        return entry

    def check_model(self, where: Any) -> None:
        """The configuration: a known cell, exactly its type's keys, each of its declared type."""
        config, refuse = self.model, Fields({}, where).refuse
        if config["cell"] not in networks.CELLS:
            refuse(f"its network's cell {config['cell']!r} is not one this mlnseq runs ({', '.join(networks.CELLS)})")
        declared = networks.config_types(config["cell"])
        if sorted(config) != sorted(declared):
            refuse(f"{MANIFEST} network 'model' is not an object of a {config['cell']}'s keys")
        for key, kind in declared.items():
            value = config[key]
            ok = {"int": _integer(value), "bool": isinstance(value, bool), "str": isinstance(value, str),
                  "float": _number(value) and math.isfinite(value) and value >= 0}.get(kind, False)
            if not ok:
                refuse(f"its network's {key} is {value!r}, not {KIND_WORDS.get(kind, kind)}")
        if not config["prior_layer"] == (self.prior is not None):
            refuse(f"its network's prior_layer ({config['prior_layer']!r}) and PriorLayer input ({self.prior!r}) "
                   "disagree")

    def check_sizes(self, n_features: int, n_classes: int, where: Any) -> None:
        """Its sizes: the manifest's features and classes, counts within bounds, a bounded receptive field."""
        config, refuse = self.model, Fields({}, where).refuse
        sizes = {"hidden_size": None, "n_features": n_features, "n_classes": n_classes,
                 **{key: None for key in ("kernel_size", "levels") if key in config}}
        for key, expected in sizes.items():
            if not (0 < config[key] <= max(NETWORK_SIZE_LIMIT, expected or 0)) \
                    or (expected is not None and config[key] != expected):
                declared = expected if expected is not None else f"a count up to {NETWORK_SIZE_LIMIT}"
                refuse(f"its network's {key} is {config[key]!r}, but the manifest declares {declared}")
        if "levels" in config:  # each level doubles the dilation: bounded by the levels, whatever the kernel
            if config["kernel_size"] < 2 or config["levels"] > MAX_LEVELS:
                refuse(f"its network's kernel_size must be 2 or more and levels at most {MAX_LEVELS}, got "
                       f"{config['kernel_size']} and {config['levels']}")
            if (config["kernel_size"] - 1) * 2 ** config["levels"] > RECEPTIVE_FIELD_LIMIT:
                refuse(f"its network's receptive field is over {RECEPTIVE_FIELD_LIMIT:,} frames")


def _timing_fields(values: dict[str, Any], where: Any) -> dict[str, Any]:
    """The decoder's lag, latency, rate and start distribution, checked (defaults where an older file lacks them)."""
    classes = values.get("classes")
    timing = Timing.read(values, where, len(classes) if isinstance(classes, list) else 0)
    return {"lag": timing.decoding.lag, "latency_s": timing.latency_s, "rate_hz": timing.rate_hz, "start": timing.start}


@dataclass(frozen=True)
class Manifest:
    """What a model file declares: the recogniser (method, decoding, MLN mode and paper floor, network factor
    weight), its classes and features, how its recordings are read, where it came from, and its members."""

    mlnseq_version: str
    created: str
    method: Method
    decode: str
    mln_mode: MLNMode
    paper_floor: PaperFloor
    network_weight: float | None  # decoded network methods: the network factor's weight (>= 0)
    network_weight_how: WeightSource | None
    chosen_by_cross_validation: Chosen | None
    validation_frame_accuracy: float | None
    classes: list[str]
    features: list[str]
    source: str  # the recordings' source, as collect named it (shown by info; predict reads ``reading``)
    reading: dict[str, Any]  # how predict reads new recordings: env, columns, source options
    predicates: list[str]
    network: NetworkEntry | None
    inputs: dict[str, str]  # workdir file name -> digest
    notes: list[str]
    formulas: int = 0
    members: dict[str, dict[str, Any]] = field(default_factory=dict)  # name -> {bytes, sha256}
    format: int = MODEL_FORMAT
    lag: int | None = None  # frames a lagged decoder waits (0 for filter, None offline or undecoded)
    latency_s: float | None = None  # the lag in seconds where the recordings' rate is known
    rate_hz: float | None = None  # the recordings' frame rate, where known
    start: list[float] | None = None  # the chains' start distribution (log, per class), fitted on training episodes

    @property
    def decoding(self) -> Decoding:
        """The decoder with its lag."""
        return Decoding(Decoder(self.decode), self.lag if Decoder(self.decode).lagged else None)

    @classmethod
    def read(cls, values: Any, where: Any) -> Manifest:
        """A manifest from its JSON object, every field checked (the format first, by model_file)."""
        read = Fields(values, where)
        unknown = sorted(set(values) - {f.name for f in fields(cls)})
        if unknown:
            read.refuse(f"{MANIFEST} holds {unknown[0]!r}, which is not a field of a format {MODEL_FORMAT} manifest")
        network = read.get("network")
        chosen = read.get("chosen_by_cross_validation")
        manifest = cls(
            read.text("mlnseq_version"), read.text("created"), read.choice("method", Method),
            read.text("decode"), read.choice("mln_mode", MLNMode), read.choice("paper_floor", PaperFloor),
            read.number("network_weight", 0, math.inf, optional=True),
            read.choice("network_weight_how", WeightSource, optional=True),
            None if chosen is None else Chosen.read(chosen, where),
            read.number("validation_frame_accuracy", 0, 1, optional=True),
            read.names("classes", empty=False), read.names("features", empty=False), read.text("source"),
            read.mapping("reading", _option, "an object of option -> value"),
            read.names("predicates", empty=True), None if network is None else NetworkEntry.read(network, where),
            read.mapping("inputs", _text, "an object of file name -> digest"),
            read.names("notes", empty=True, unique=False), read.count("formulas"),
            read.mapping("members", _member, "an object of member name -> {bytes, sha256}"), read.count("format"),
            **_timing_fields(values, where))
        read.check("members", set(manifest.members) <= {SPEC, WEIGHTS, NETWORK, AUDIT},
                   f"an object of member name ({SPEC}, {WEIGHTS}, {NETWORK}, {AUDIT}) -> {{bytes, sha256}}")
        manifest.check(where)
        return manifest

    def check(self, where: Any) -> None:
        """The fields against each other: the network is the method's, of the manifest's sizes."""
        refuse = Fields({}, where).refuse
        if (None if self.network is None else self.network.name) != network_of(self.method):
            name = None if self.network is None else str(self.network.name)
            refuse(f"its manifest's network {name!r} is not one this mlnseq runs for method {self.method}")
        if self.network is not None:
            self.network.check_sizes(len(self.features), len(self.classes), where)
        if self.chosen_by_cross_validation is not None and self.chosen_by_cross_validation.method != self.method:
            refuse(f"its manifest's method {self.method} is not the one chosen by cross-validation")

    def to_dict(self) -> dict[str, Any]:
        """The JSON object manifest.json holds (enum members as their names)."""
        return json_ready(asdict(self))


def json_ready(value: Any) -> Any:
    """``value`` with enum members as their string values, for JSON."""
    if isinstance(value, Enum):
        return value.value
    if isinstance(value, dict):
        return {k: json_ready(v) for k, v in value.items()}
    if isinstance(value, list):
        return [json_ready(v) for v in value]
    return value
