"""``mavastsm sweep``: robustness maps of the controllers over swept disturbances, inertia variation, sensor noise,
loop and link, at the torque level (batched offline simulator) or over MAVLink (bridge + simulated Solo pairs).

Modules: ``spec`` (the validated sweep YAML), ``run_inputs`` (what one run flies, its outcome), ``offline_level``
and ``mavlink_level`` (one unit of work per level), ``executors`` (local processes or Dask), ``store`` (resume),
``engine`` (run), ``outputs`` (margin table, maps), ``command`` (the CLI).
"""
