"""Why a model decided what it did, term by term (docs/explain.md): the terms (`terms.py`), what a method scores
with (`explainer.py`), the decoded and undecoded margins (`decoded.py`, `undecoded.py`), a recording's frames
(`frames.py`), a segment's why (`segments.py`), a stream's (`streaming.py`), the 80-column table (`text.py`) and a
predicate changed (`what_if.py`)."""
