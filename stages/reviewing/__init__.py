"""`mlnseq review`'s pieces: the recordings decided (decisions.py), what a fit's workdir tells them (fitted.py), what
the page shows (views.py), the labels it saves (corrections.py), the site the guarded server serves (site.py) and the
page itself (page/: HTML, script and style, with uPlot bundled from npm, never fetched from elsewhere)."""
