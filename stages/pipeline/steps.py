"""What ``fit`` returns and tells its observer: each stage's typed result (``CollectStep`` ... ``TrainStep``) with
the line it is said in (plain text, paths as the workdir was given), and ``Fitted``, the model file with the choice
said back."""

from __future__ import annotations

import enum
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from mlnseq.catalog.decoders import Decoder, Decoding
from mlnseq.catalog.methods import decoded_name
from mlnseq.catalog.notes import counted
from mlnseq.choosing.cross_validation import figures_said
from mlnseq.choosing.folds import MOST_FOLDS
from mlnseq.choosing.latency import Standing

if TYPE_CHECKING:
    from mlnseq.binarize import Binarized
    from mlnseq.choosing.folds import Folds
    from mlnseq.conflate import ConflateResult
    from mlnseq.export import Exported
    from mlnseq.formulas import WrittenFormulas
    from mlnseq.labelling.label_next import Proposal
    from mlnseq.learn_weights import Learned
    from mlnseq.model.manifest import Manifest
    from mlnseq.sources.recording import Collected
    from mlnseq.train import TrainResult

RULE = ("among those with the network alone's frame accuracy or more and within one standard error of the best "
        "frame accuracy, the best mean of segment accuracy, frame accuracy and edit (the test split unread; "
        "docs/choosing.md)")


class FormulasFrom(enum.Enum):
    LEARNED = "the formulas learned with the predicates"
    YOURS = "your formulas"
    TEMPLATE = "the built-in temporal.mln: each predicate value => each class, transitions"


@dataclass(frozen=True)
class CollectStep:
    path: Path  # frames.parquet
    collected: Collected
    rate_hz: float | None  # the recordings' frame rate, where known
    budget: int | None  # frames a frame may wait (None: offline)

    @property
    def said(self) -> list[str]:
        """With few labelled recordings and no test split: that every one trains."""
        from mlnseq.sources.recording import clicked_episodes
        from mlnseq.sources.splits import FEW_LABELLED

        splits, meta = self.collected.frames["split"], self.collected.meta
        aligned = (meta.get("aligned") or {}).get("labelled", 0)  # labelled by alignment, not by the user
        clicked = len(clicked_episodes(meta.get("clicks", [])))  # these always train (sources/table.py)
        labelled = self.collected.frames.filter(splits != "unlabelled")["episode"].n_unique() - aligned - clicked
        if not labelled or labelled >= FEW_LABELLED or (splits == "test").any():
            return []
        return [f"{counted(labelled, 'labelled recording')}, fewer than {FEW_LABELLED}: every one trains, none is "
                "spent on a test split; the cross-validated figures are the estimate"]


@dataclass(frozen=True)
class BinarizeStep:
    path: Path  # predicates.parquet
    binarized: Binarized
    spec: Path  # the spec binarized with: yours, or the learned one
    learned: dict | None  # what binarize --suggest learned (its record), None with your spec
    learned_formulas: Path | None  # the formulas learned with it, beside it

    @property
    def said(self) -> str:
        columns = self.binarized.meta["predicates"]
        return (f"{counted(len(columns), 'predicate')}, {counted(sum(map(len, columns.values())), 'column')} from "
                f"{'the learned spec' if self.learned else 'your spec'} {self.spec}; `mlnseq binarize --table -w "
                f"{self.path.parent}` shows which separate which classes")


@dataclass(frozen=True)
class FoldStep:
    k: int  # 0: none
    folds: Folds | None  # how the training split was cut
    asked: int | None  # FitOptions.folds (None: fit's default)
    training_episodes: int

    @property
    def why_none(self) -> str:
        return ("--folds 0" if self.asked == 0 else "a training split too small for 2 folds" if self.training_episodes
                != 1 else "one training recording whose task never restarts: blocks of it would hold whole phases out")

    @property
    def said(self) -> str:
        if self.folds is None:
            return f"none ({self.why_none}): nothing is chosen by cross-validation"
        return (f"{self.folds.describe()} ({counted(self.training_episodes, 'training episode')}"
                + ("" if self.asked is not None else f"; fit's default: one per episode, at most {MOST_FOLDS}")
                + "): cross-validation chooses the network's weight and the method")


@dataclass(frozen=True)
class FormulasStep:
    written: WrittenFormulas  # WORKDIR/formulas.mln
    spec: Path  # the formulas file it was written from
    origin: FormulasFrom

    @property
    def said(self) -> str:  # the built-in file is named, its path (inside the package) is not
        shown = "" if self.origin is FormulasFrom.TEMPLATE else f" ({self.spec})"
        return f"{self.written.path} from {self.origin.value}{shown}"


@dataclass(frozen=True)
class WeightsStep:
    learned: Learned
    learned_mln: Path  # every expanded formula with its weight
    folds: int

    @property
    def said(self) -> str:
        return (f"{counted(self.learned.weights.height, 'formula')} weighted ({self.learned.objective}), each with its "
                f"weight in {self.learned_mln}" + (f", and each of the {self.folds} folds' without it"
                                                   if self.folds else ""))


@dataclass(frozen=True)
class TrainStep:
    result: TrainResult
    folds: int

    @property
    def said(self) -> str:
        return (f"{self.result.checkpoint} (stream mode: whole episodes, as live frames come"
                + (f"; {self.folds} fold networks for out-of-fold predictions" if self.folds else "") + ")")


@dataclass(frozen=True)
class TestFigures:
    frame_accuracy: float  # fractions of the test split's frames and segments
    segment_accuracy: float


@dataclass(frozen=True)
class Fitted:
    """What ``fit`` made and chose, and each stage's result on the way."""

    exported: Exported  # the model file's path and manifest (its chosen_by_cross_validation: the choice's record)
    standing: Standing | None  # the choice, runner-up and network alone, cross-validated; None without folds
    test: dict[str, TestFigures]  # the choice's and the network alone's on the test split (empty: no test split)
    collected: CollectStep
    binarized: BinarizeStep
    folding: FoldStep
    formulas: FormulasStep
    weights: WeightsStep
    trained: TrainStep
    conflated: ConflateResult
    proposal: Proposal | None = None  # the unlabelled recordings ranked (label_next.csv), None without any
    proposal_files: tuple[Path, ...] = ()  # label_next.csv and the predicted phases

    @property
    def path(self) -> Path:
        return self.exported.path

    @property
    def manifest(self) -> Manifest:
        return self.exported.manifest

    @property
    def method(self) -> str:
        """The method and decoding chosen, as predictions name it (``conflation+smooth-legal@5``)."""
        manifest = self.manifest
        return decoded_name(manifest.method, Decoding(Decoder(manifest.decode), manifest.lag).name)

    @property
    def budget(self) -> int | None:
        """Frames each frame may wait (None: offline)."""
        return self.collected.budget

    @property
    def said(self) -> list[str]:
        """The choice and why, the runner-up, the network alone and a steadier candidate with their cross-validated
        figures (segment / frame / edit, and their mean), then the test split's figures."""
        standing = self.standing
        lines = [] if standing else [f"chose {self.method} (network and MLN) without cross-validation "
                                     f"({self.folding.why_none}): nothing to choose on"]
        roles = ((standing.chosen, "chose"), (standing.runner_up, "runner-up"),
                 (standing.network_alone, "network alone"), (standing.steadier, "steadier")) if standing else ()
        for candidate, role in roles:
            if candidate is not None:
                lines.append(f"  {role + ':':<15}{candidate.name:<24} "
                             + figures_said(candidate.figures, candidate.score[0]))
        if standing:
            lines.append(f"chose {standing.chosen.name} of {standing.among} candidates within the budget by "
                         f"{self.folding.k}-fold cross-validation on the training split: {RULE}")
            lines += self.estimated_said
        if standing and standing.steadier is not None:
            lines.append(steadier_line(standing, self.collected.path.parent))
        if self.test:
            lines.append("test split (held out of everything above): " + "; ".join(
                f"{name} frame accuracy {t.frame_accuracy:.1%}, segment accuracy {t.segment_accuracy:.1%}"
                for name, t in self.test.items()))
        if self.proposal is not None:
            ranked, phases = self.proposal_files
            what, which = (("label one on every frame next, to say where the clicked ones' phases begin", "each")
                           if self.proposal.clicked else ("label next", "every unlabelled recording"))
            lines.append(f"{what} ({ranked}; the phases of {which} to correct in {phases}, from "
                         f"{self.proposal.starts_from}: {self.proposal.why}; `mlnseq review {self.path} -w "
                         f"{ranked.parent}` shows them):")
            lines += [f"  {line}" for line in self.proposal.first(3)]
        return lines

    @property
    def estimated_said(self) -> list[str]:
        """Where the folds score against labels fit estimated (between clicks, by alignment): how many, and, where
        only clicks label the training recordings, that the figures cannot be trusted yet."""
        from mlnseq.labelling.estimates import counted

        estimated = counted(self.collected.collected.frames, self.collected.collected.meta)
        if not estimated.frames:
            return []
        lines = [f"  the folds score against {estimated.frames:,} labelled frames fit estimated ({estimated.said()}) "
                 "beside those you gave: where the estimates are wrong, these figures read too high"]
        if not estimated.exact_recordings and estimated.between_clicks:
            lines.append("  only clicks label the training recordings: these figures cannot be trusted until one "
                         "recording is labelled on every frame (label_next.csv ranks which)")
        return lines

    @property
    def wrote(self) -> str:
        """The model file, what it decodes with, within which budget, and what to run next."""
        manifest, budget = self.manifest, self.budget
        why = ("offline, over whole recordings" if budget is None else "online, as live frames come" if not budget
               else f"within {counted(budget, 'frame')} of each frame")
        return (f"wrote {self.path} ({manifest.method}, decode {manifest.decode}"
                f"{'' if manifest.lag is None else f' at lag {manifest.lag}'}: {why}); next: `mlnseq predict "
                f"{self.path} --source NEW` or `mlnseq stream {self.path}`")


def steadier_line(standing: Standing, workdir: Path) -> str:
    """What the steadier candidate gives up and gains against the choice, and the command that deploys it."""
    chosen, other = standing.chosen, standing.steadier
    decoding = other.decoding
    lag = f" --lag {decoding.lag}" if decoding.decoder.lagged else ""
    lost = chosen.figures["frame_accuracy"] - other.figures["frame_accuracy"]
    return (f"for live use, {other.name} flickers far less: {abs(lost):.1f} points of cross-validated frames "
            f"{'fewer' if lost > 0 else 'more'}, edit {other.figures['edit'] - chosen.figures['edit']:.1f} points "
            f"higher (docs/choosing.md); `mlnseq export -w {workdir} --method {other.method} --decode "
            f"{decoding.decoder.value}{lag} -o FILE` deploys it")
