"""Policy evaluation as a job: spec, worlds, runner (in process or on Dask), report, plot."""
