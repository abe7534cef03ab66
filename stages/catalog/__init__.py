"""The ground floor: the workdir's file names, Parquet schemas and atomic I/O, errors, notes, method names."""
