"""Built-in regulation tables (TOML data files, one per regulation); read by :mod:`measure.limits`."""
