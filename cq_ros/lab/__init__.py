"""The lab around the science: running grids of seeded runs (on this machine's cores or a Dask cluster), the
result files and their one schema, summaries, the paper's figures, episode animations and the reproduction."""
