"""The report's pieces: loading runs, tables, figures, claims and rendering."""
