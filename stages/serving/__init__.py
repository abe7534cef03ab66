"""A page served to the browser on the user's own machine, guarded as a door: only its own Host and Origin, only
the files it was given, bounded request bodies (guarded.py)."""
