"""Labelling less: which recording to label next, and the phases proposed for every recording given without labels
(``label_next.py``). Labels filled at collect, from clicks or by alignment, are the sources' (``sources/clicks.py``,
``sources/alignment.py``)."""
