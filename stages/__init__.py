"""mlnseq: sequential activity recognition with logic constraints (a network and a Markov Logic Network).

The Python API recognises with a model file written by `mlnseq export`, on the base install alone (numpy,
polars, pyarrow: no torch)::

    import mlnseq

    recognizer = mlnseq.load("combined.mlnseq")            # a Recognizer, loaded once
    prediction = recognizer.step({"arm_distance": 0.31, "left_gripper": 0.52, "right_gripper": 0.98})
    prediction.name, prediction.probabilities              # the class, every class's probability (classes order)
    prediction.restarted                                   # no allowed transition reached it: the filter restarted
    recognizer.reset()                                     # the next frame starts a new episode
    probabilities, classes = recognizer.predict(features)  # a whole recording [frames, features], offline
    recognizer.restarts                                    # (episode, frame) where that predict restarted its chain
    recognizer.explain(1234)                               # why frame 1234 of it got its class, term by term

``recognizer.features`` names the values a frame holds (``step`` also takes them in that order) and
``recognizer.classes`` the classes. A frame with a missing, non-numeric or non-finite value raises
``mlnseq.BadInput`` naming the feature, and leaves the recogniser's state untouched.

``mlnseq.fit`` makes a model file from labelled recordings, as ``mlnseq fit`` does (it needs the ``train`` extra);
its source options are collect's (``mlnseq.collect.CollectOptions``)::

    from mlnseq.collect import CollectOptions, SourceOptions

    source = CollectOptions(env="rosbag", source="bags", recordings=SourceOptions(label_topic="/phase"))
    fitted = mlnseq.fit(source, "arm-work", mlnseq.FitOptions(epochs=100, lag=5, output="arm.mlnseq"))
    fitted.path, fitted.method                             # the model file; what it chose ("conflation+filter")
    fitted.standing.chosen.figures                         # its cross-validated figures (runner_up, network_alone)
    fitted.test                                            # the choice's and the network alone's on the test split
    fitted.said                                            # the lines `mlnseq fit` prints about the choice

Each stage's result is in it (``fitted.collected`` ... ``fitted.conflated``); ``observer=`` (an
``mlnseq.pipeline.fit.Observer``) hears each stage as it finishes. Bad options raise ``mlnseq.BadInput`` before any
work.

``mlnseq.sweep`` runs a sweep file (a grid of train, conflate and export options times seeds) as ``mlnseq sweep``
does: ``mlnseq.sweep("sweep.toml", mlnseq.SweepOptions(cores=2)).best`` is the best config by cross-validation.

Inside, the package's modules are the pipeline's stages, one per command (``mlnseq.collect`` ...
``mlnseq.stream``: a pure function on data and a small ``run`` doing the file I/O), and its folders the
libraries they share (docs/layout.md).
"""

from __future__ import annotations

import os
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from mlnseq.recognition.recognizer import Recognizer

__all__ = ["load", "fit", "FitOptions", "sweep", "SweepOptions", "Recognizer", "Prediction", "BadInput"]

# The MLN engine's small matrix products run fastest on one BLAS thread; several threads contend on a
# shared 2-core machine and made weight learning 30 times slower under load. Users may still override.
for _variable in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_variable, "1")


def load(path: str | os.PathLike[str]) -> Recognizer:
    """The recogniser in a model file written by `mlnseq export`; a file that is not one, truncated or from an
    incompatible mlnseq raises ``mlnseq.BadInput`` saying so."""
    from mlnseq.recognition.recognizer import Recognizer

    return Recognizer.load(path)


def __getattr__(name: str) -> Any:
    """The API's classes, imported when first named: ``import mlnseq`` itself stays light."""
    if name in ("Recognizer", "Prediction"):
        from mlnseq.recognition import recognizer

        return getattr(recognizer, name)
    if name in ("fit", "FitOptions"):  # the callers of the pipeline beside the command line
        from mlnseq.pipeline import fit

        return getattr(fit, name)
    if name in ("sweep", "SweepOptions"):
        from mlnseq.pipeline import sweep

        return getattr(sweep, name)
    if name == "BadInput":
        from mlnseq.catalog.errors import BadInput

        return BadInput
    raise AttributeError(f"module 'mlnseq' has no attribute {name!r}")
