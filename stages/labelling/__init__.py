"""Labelling less: few labels turned into many at collect (recordings without labels labelled by aligning them in time
to the labelled ones, ``alignment.py``; the boundaries between clicks learned, ``clicks.py``), and which recording to
label next with the phases proposed for each (``label_next.py``). The labels themselves are read by ``sources/``."""
