"""The compiled station stop (DESIGN rule 1, one model for every stop; rule 2, a few named records).

- :mod:`railstop.model.records`: the record layouts (parameters, the run's
  parameters, state, outputs) and the constants of their packed arrays;
- :mod:`railstop.model.step`: ``stop_init``, ``stop_step`` (one 10 ms step),
  ``stop_finish``;
- :mod:`railstop.model.run`: ``simulate_run``, ``simulate_block`` and
  ``run_kernel``, the Python entry;
- :mod:`railstop.model.build`: ``KernelModel``, station, vehicle and
  controller data as the records' arrays.
"""
