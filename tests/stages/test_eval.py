"""eval: its options (the metrics: test_metrics.py; the stage on real predictions: test_bad_inputs, test_report)."""

import pytest

from stages import eval as stage
from stages.errors import BadInput


@pytest.mark.parametrize("options", [stage.EvalOptions(fraction=0.0), stage.EvalOptions(fraction=1.2),
                                     stage.EvalOptions(method="hmm")])
def test_bad_options_are_refused(options):
    with pytest.raises(BadInput):
        options.validate()
