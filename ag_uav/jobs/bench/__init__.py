"""``ag-uav bench``: the speed figures, measured in one process and one run.

:mod:`~ag_uav.jobs.bench.suite` runs the whole bench (``ag-uav bench``) and prints it; its pieces,
each also runnable alone where it says so:

- :mod:`~ag_uav.jobs.bench.physics`: MuJoCo alone replaying the batch's flights (the yardstick);
- :mod:`~ag_uav.jobs.bench.workers`: missions on a local pool of worker processes;
- :mod:`~ag_uav.jobs.bench.estimators`: the filters' predict and update against filterpy;
- :mod:`~ag_uav.jobs.bench.map_topics`: the cost of the log's map topics
  (``python -m ag_uav.jobs.bench.map_topics``);
- :mod:`~ag_uav.jobs.bench.first_run`: the first run on an empty kernel cache
  (``python -m ag_uav.jobs.bench.first_run``);
- :mod:`~ag_uav.jobs.bench.vehicles`: the default mission on each vehicle preset against MuJoCo
  stepping its own model (``python -m ag_uav.jobs.bench.vehicles``);
- :mod:`~ag_uav.jobs.bench.big`: a 38 ha job with the full log
  (``python -m ag_uav.jobs.bench.big``).
"""
