"""Services: the work behind the routes (datasets, fitting, trials, runs, rig, events)."""
