"""`mlnseq review`'s pieces: what its page shows (views.py), the labels it saves (corrections.py) and the page
itself (page/: HTML, script and style, with uPlot bundled from npm, never fetched from elsewhere)."""
