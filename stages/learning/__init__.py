"""The logic learner behind `binarize --suggest` and `fit`: what the columns offer (`suggest.py`), candidate
predicates and their thresholds (`candidates.py`), predicates and formulas chosen by cross-validation
(`learned_logic.py`, with its quick chain `quick_chain.py`), and the learned spec and formulas written and said
(`learned_spec.py`, `learned_files.py`)."""
