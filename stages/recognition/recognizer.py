"""`Recognizer`: a model file, frames in, class probabilities out (fusion and decoding from stages/fusion/).

`predict` (a model file over new recordings), `stream` (one frame at a time), the live nodes and the Python API
call this module. The networks run in numpy
(stages/networks/network.py), so a model file is recognised without torch. The method names are in
stages/catalog/methods.py, the workdir's checkpoints in stages/model/checkpoints.py, the model file in
stages/model/model_file.py and its manifest in stages/model/manifest.py.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, replace
from functools import lru_cache
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import polars as pl

from mlnseq.model import model_file
from mlnseq.timeline import sequences
from mlnseq.catalog.errors import BadInput
from mlnseq.catalog.decoders import Decoder, parse_decoding
from mlnseq.catalog.methods import (FUSED, NETWORKS, Method, MLNMode, PaperFloor, Prior, decoded_name, needs_mln,
                                    network_of)
from mlnseq.model.manifest import NETWORK, SPEC, WEIGHTS, Manifest
from mlnseq.networks.network import StreamingNetwork
from mlnseq.mln import chain
from mlnseq.mln.lag_online import Online
from mlnseq.fusion import decoding as decoders
from mlnseq.fusion.fuse import EPSILON, chain_of, frame_factor, fuse, prior_input

if TYPE_CHECKING:
    from mlnseq.predicates.spec import PredicateSpec
    from mlnseq.explaining.explainer import Scores
    from mlnseq.mln.factors import MLNFactors

# --- the Recognizer (export, info, predict, stream, the Python API) ---------------------------------


@dataclass(frozen=True)
class Prediction:
    """One frame's recognition: the class, its name and every class's probability (in class order)."""

    frame: int  # index within the episode
    label: int
    name: str
    probabilities: np.ndarray
    restarted: bool = False  # the frame was a dead end (no class possible given the previous): the chain started anew
    final: tuple[Prediction, ...] = ()  # the frames of the episode decided by this step (a lagged decoder: t - lag)
    why: list | None = None  # its largest terms as JSON-ready dicts, when it was decided (``explain_steps``)


class Recognizer:
    """A trained recogniser loaded from a model file: frames in, class probabilities out.

    ``step`` takes one frame at a time (a mapping of feature name to value, or the values in feature
    order) and keeps the state a live stream needs: the previous frame for the change predicates, the
    network's hidden state and the filter's belief. ``reset`` starts a new episode. ``predict`` runs
    whole recordings at once, offline decoding (viterbi) included.
    """

    def __init__(self, entries: dict[str, bytes], where: str = "<model>"):
        from mlnseq.predicates.rules import StreamingBinarizer
        from mlnseq.mln.factors import MLNFactors, parse_weights

        model = model_file.parse_model(entries, where)  # every manifest field checked (model/manifest.py)
        self.manifest: Manifest = model.manifest
        self.method, self.decode = self.manifest.method, self.manifest.decode
        self.decoding, self.lag = self.manifest.decoding, self.manifest.decoding.lag
        self.start = None if self.manifest.start is None else np.asarray(self.manifest.start, dtype=np.float64)
        needed = [NETWORK] * (network_of(self.method) is not None) + [SPEC, WEIGHTS] * needs_mln(self.method,
                                                                                                  self.decode)
        missing = [name for name in needed if name not in entries]
        if missing:
            raise BadInput(f"{where} lacks {', '.join(missing)}, which a {decoded_name(self.method, self.decode)} "
                           "model needs: export it again with `mlnseq export`")
        self.classes: list[str] = list(self.manifest.classes)
        self.features: list[str] = list(self.manifest.features)
        weight = self.manifest.network_weight  # learned weights may be 0: the network counts for nothing
        self.network_weight = 1.0 if weight is None else float(weight)
        self._feature_index = {name: i for i, name in enumerate(self.features)}
        self.network = model.network
        self.audit = model.audit  # the audit profile's JSON, or None (a model exported before `mlnseq audit`)
        self.prior = None if self.manifest.network is None else self.manifest.network.prior  # PriorLayer's input
        self.spec: PredicateSpec | None = None
        self.weights: pl.DataFrame | None = None
        self.mln: MLNFactors | None = None
        self.formulas: tuple = ()
        self.last: Scores | None = None  # the recording the last ``predict`` scored, for ``explain``
        if needs_mln(self.method, self.decode):
            self.spec, self.weights = model.spec, model.weights
            self.columns = [c for columns in self.spec.columns().values() for c in columns]
            self.binarizer = StreamingBinarizer(self.spec, self.features)
            formulas = parse_weights(self.weights, self.columns, self.classes)
            self.formulas = tuple(formulas)  # the formulas that count, in the weights' order
            self._per_frame = [f for f in formulas if not f.temporal]
            if self.decode != "none":
                self.mln = MLNFactors(formulas, self.columns, len(self.classes))
        self._mln_row = lru_cache(maxsize=4096)(self._mln_of)
        self.restarts: list[tuple[Any, int]] = []  # where the last ``predict`` restarted its chain: (episode, frame)
        self._explaining = None  # explain_steps: a LiveExplainer
        self.stepped: tuple = (None, None, None)  # the last frame stepped: its predicate values, chain factor, pairwise
        self.reset()

    @classmethod
    def load(cls, path: str | Path) -> Recognizer:
        """Load an ``.mlnseq`` file written by `mlnseq export`."""
        return cls(model_file.read_model(Path(path)), str(path))

    # -- one frame at a time ---------------------------------------------------------------------

    def reset(self) -> None:
        """The next frame starts a new episode."""
        self._frame = 0
        self._evidence: np.ndarray | None = None
        self._network = StreamingNetwork(self.network) if self.network is not None else None
        self._filter = chain.Filter(len(self.classes)) if self.decode != "none" else None
        self._online = None  # a lagged or legal decoder's buffer (filter and the offline decoders: the filter)
        if self.decode != "none" and self.decoding.decoder is not Decoder.FILTER and not self.decoding.decoder.offline:
            self._online = Online(len(self.classes), self.decoding)
        if self.spec is not None:
            self.binarizer.reset()
        if self._explaining is not None:
            self._explaining.reset()

    def decoded_with(self, decode: str) -> None:
        """From now on ``step`` decodes with ``decode`` (``smooth-legal@5``, as predict's --decode), the model's factors
        kept; an offline decoder steps as the filter. A new episode starts."""
        decoding = parse_decoding(decode)
        if decoding.name != self.decoding.name and decoding.decoder is not Decoder.NONE and self.mln is None:
            raise BadInput(f"--decode {decode}: this model was exported without decoding, so it holds no "
                           "transition factors; export it again with --decode filter or viterbi")
        self.decoding, self.decode, self.lag = decoding, decoding.decoder.value, decoding.lag
        self.reset()

    def explain_steps(self, count: int) -> None:
        """From now on each frame a step decides (a Prediction, or one of its ``final``) carries ``why``: the
        ``count`` largest terms of its margin (as ``explain`` gives them); 0 stops."""
        from mlnseq.explaining.streaming import LiveExplainer

        self._explaining = LiveExplainer(self, count, EPSILON) if count else None

    @property
    def next_frame(self) -> int:
        """The index within the episode that the next ``step``'s frame gets."""
        return self._frame

    def vector(self, frame: Mapping[str, Any] | Sequence[float] | np.ndarray) -> np.ndarray:
        """A frame's feature values in the model's order, as float64; refuses missing and non-finite values."""
        if isinstance(frame, Mapping):
            missing = [name for name in self.features if name not in frame]
            if missing:
                raise BadInput(f"missing feature {', '.join(map(repr, missing))}")
            values = [frame[name] for name in self.features]
            if not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in values):
                bad = next(n for n, v in zip(self.features, values)
                           if not isinstance(v, (int, float)) or isinstance(v, bool))
                raise BadInput(f"feature {bad!r} is {frame[bad]!r}, not a number")
            vector = np.array(values, dtype=np.float64)
        else:
            vector = np.asarray(frame, dtype=np.float64).reshape(-1)
            if vector.shape != (len(self.features),):
                raise BadInput(f"a frame has {len(self.features)} feature values ({', '.join(self.features)}), "
                               f"got {vector.size}")
        if not np.isfinite(vector).all():
            bad = self.features[int(np.flatnonzero(~np.isfinite(vector))[0])]
            raise BadInput(f"feature {bad!r} is {vector[self._feature_index[bad]]}, not a finite number")
        return vector

    def step(self, frame: Mapping[str, Any] | Sequence[float] | np.ndarray, decide: bool = True) -> Prediction:
        """Recognise the next frame of the current episode from its raw features. ``decide=False`` holds a lagged
        decoder's decisions back until :meth:`decide` (frames at hand decided together, faster); its ``final`` is
        then empty."""
        x = self.vector(frame)
        # predicates from the values as a frames table holds them (float32), as `predict` binarizes them
        evidence = self.binarizer.step(x.astype(np.float32)) if self.spec is not None else None
        p_mln = prior = unary = None
        if evidence is not None:
            p_mln, prior, unary = self._mln_row(evidence.tobytes())
        log_p_network = None if self._network is None else self._network.step(x, prior)
        explaining = self._explaining
        self.stepped = (evidence, None, None)
        if self._filter is None:
            probabilities = fuse(self.method, None if log_p_network is None else np.exp(log_p_network), p_mln)
            if explaining is not None:
                explaining.record_undecoded(self._frame, evidence, log_p_network, p_mln)
        else:
            factor = frame_factor(self.method, unary, log_p_network, self.network_weight)
            if self._evidence is None and self.start is not None:  # an episode's first frame: the start distribution
                factor = factor + self.start
            pairwise = None if self._evidence is None else self.mln.pairwise(self._evidence[None], evidence[None])[0]
            self.stepped = (evidence, factor, pairwise)
            if explaining is not None:
                explaining.record(self._frame, evidence, log_p_network, factor, pairwise)
            if self._online is not None:
                return self._step_online(evidence, factor, pairwise, decide)
            probabilities = np.exp(self._filter.step(factor, pairwise))
        self._evidence = evidence
        label = int(np.argmax(probabilities))
        restarted = self._filter is not None and self._filter.restarted
        why = None
        if explaining is not None:
            if self._filter is not None:
                explaining.stepped(self._frame, probabilities, restarted)
            why = explaining.decided(self._frame, label, probabilities)
        prediction = Prediction(self._frame, label, self.classes[label], probabilities, restarted, why=why)
        self._frame += 1
        return replace(prediction, final=(prediction,))

    def _step_online(self, evidence: np.ndarray, factor: np.ndarray, pairwise: np.ndarray | None,
                     decide: bool) -> Prediction:
        """A lagged or legal decoder's step: the current frame's filtered belief, and the frames decided by it."""
        decided = self._online.step(factor, pairwise, decide)
        if self._explaining is not None:  # the belief after this frame, before its decisions are explained
            self._explaining.stepped(self._frame, self._online.current, self._online.restarted)
        final = self._finals(decided)
        self._evidence = evidence
        probabilities = self._online.current
        label = int(np.argmax(probabilities))
        prediction = Prediction(self._frame, label, self.classes[label], probabilities, self._online.restarted,
                                final)
        self._frame += 1
        return prediction

    def _finals(self, finals: list) -> tuple[Prediction, ...]:
        explaining = self._explaining
        return tuple(Prediction(f.index, f.label, self.classes[f.label], f.probabilities, f.restarted,
                                why=None if explaining is None else explaining.decided(f.index, f.label,
                                                                                       f.probabilities))
                     for f in finals)

    def decide(self) -> tuple[Prediction, ...]:
        """The frames that ``step(..., decide=False)`` held back and whose lag has passed, decided."""
        return () if self._online is None else self._finals(self._online.decide())

    def finish(self) -> list[Prediction]:
        """The episode (or the input) ended: decide its pending frames at once (a lagged decoder's last ``lag``
        frames); ``reset`` then starts the next. Decoders without a lag have none pending."""
        return [] if self._online is None else list(self._finals(self._online.finish()))

    def _mln_of(self, evidence: bytes) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """The MLN's per-frame class probabilities, PriorLayer input and chain factor of one evidence row."""
        from mlnseq.mln import classifier
        from mlnseq.mln.factors import frame_scores

        row = np.frombuffer(evidence, dtype=bool)[None]
        scores = frame_scores(self._per_frame, row, self.columns, len(self.classes), classifier.HARD_WEIGHT)
        log_p_mln, prior = self._mln_outputs(scores)
        unary = self.mln.unary(row)[0] if self.mln is not None else None
        return np.exp(log_p_mln[0]), None if prior is None else prior[0], unary

    def _mln_outputs(self, scores: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
        """The MLN's class log-probabilities [n, C] from its class scores, and PriorLayer's input if the network has
        one."""
        from mlnseq.mln import classifier

        floor = self.manifest.paper_floor
        log_p_mln = classifier.class_log_probs(scores, self.manifest.mln_mode, floor)
        return log_p_mln, None if self.prior is None else prior_input(scores, self.prior, floor)

    # -- whole recordings --------------------------------------------------------------------------

    def predict_names(self, features: np.ndarray, episodes: np.ndarray | None = None,
                      decode: str | None = None) -> tuple[np.ndarray, list[str]]:
        """As :meth:`predict`, with the predicted classes by name: (probabilities [T, C], class names [T])."""
        probabilities, predicted = self.predict(features, episodes, decode)
        return probabilities, [self.classes[int(k)] for k in predicted]

    def predict(self, features: np.ndarray, episodes: np.ndarray | None = None,
                decode: str | None = None) -> tuple[np.ndarray, np.ndarray]:
        """(class probabilities [T, C], predicted class indices [T] into ``self.classes``: names by
        :meth:`predict_names`) of recordings given as raw features [T, F] in the
        model's feature order, rows grouped by ``episodes`` (default: one episode). ``decode`` overrides the
        model's decoding (e.g. viterbi for a filter model: the same factors, decoded offline). Where a frame is a
        dead end (no class possible given the previous ones), the chain restarts there, as ``step`` does:
        ``restarts`` then lists (episode, frame within it) of each. ``explain`` then explains its frames."""
        self.last = self.scored(features, episodes, decode)
        return self.last.probabilities, self.last.path

    def scored(self, features: np.ndarray, episodes: np.ndarray | None = None, decode: str | None = None,
               edit: Callable[[np.ndarray], np.ndarray] | None = None) -> Scores:
        """:meth:`predict`'s classes and probabilities with what they were scored from (``explaining.Scores``);
        ``edit`` changes the evidence (predicate values [T, W]) before it is scored (a what-if)."""
        from mlnseq.explaining.explainer import Scores

        decode = self.decoding.name if decode is None else decode
        if decode != self.decoding.name and decode != "none" and self.mln is None:
            raise BadInput(f"--decode {decode}: this model was exported without decoding, so it holds no "
                           "transition factors; export it again with --decode filter or viterbi")
        features = np.asarray(features, dtype=np.float64)
        episodes = np.zeros(len(features), dtype=np.int64) if episodes is None else np.asarray(episodes)
        self.restarts = []
        spans = sequences.runs(episodes)
        frame_of = np.concatenate([np.arange(s.stop - s.start) for s in spans]) if spans else np.zeros(0, np.int64)
        starts = chain.chain_starts(episodes)
        log_p_mln = prior = evidence = None
        if self.spec is not None:
            from mlnseq.predicates import rules as predicate_rules
            from mlnseq.mln import classifier

            # binarized as frames.parquet holds them: float32
            evidence = predicate_rules.features_evidence(self.spec, self.features, features.astype(np.float32), starts)
            evidence = evidence if edit is None else edit(evidence)
            predicates = pl.DataFrame({column: evidence[:, i] for i, column in enumerate(self.columns)})
            log_p_mln, prior = self._mln_outputs(classifier.class_scores(predicates, self.weights, self.classes))
        log_p_network = None if self.network is None else self.network.log_probs(spans, features, prior)
        if decode == "none":
            probabilities = fuse(self.method, None if log_p_network is None else np.exp(log_p_network),
                                 None if log_p_mln is None else np.exp(log_p_mln))
            return Scores(evidence, log_p_network, log_p_mln, None, probabilities.argmax(1), probabilities, decode,
                          episodes, frame_of)
        factors = chain_of(self.method, self.mln, evidence, starts, log_p_network, self.network_weight, self.start)
        decoded = decoders.decode(factors, decode)
        self.restarts = [(episodes[t].item(), int(frame_of[t])) for t in decoded.restarts]
        return Scores(evidence, log_p_network, log_p_mln, factors, decoded.path, decoded.probabilities, decode,
                      episodes, frame_of)

    def explain(self, frame: int | Mapping[str, Any] | Sequence[float] | np.ndarray, versus: str | None = None,
                episodes: np.ndarray | None = None, decode: str | None = None) -> Any:
        """Why a frame got its class: an ``Explanation`` (its margin over the runner-up, or over the class
        ``versus``, as terms that add up to it; docs/explain.md). ``frame``: a row of the recording the last
        :meth:`predict` was given; or a whole recording's features [T, F] (rows grouped by ``episodes``): then a
        list, one per frame; or one frame's features: a recording of that frame alone."""
        from mlnseq.explaining.frames import explain_recognized

        return explain_recognized(self, frame, versus, episodes, decode, EPSILON)
