"""Plots and reports from a model folder's stored logs.

- :mod:`laplab.analysis.loaders`: pure readers (TrainingMetrics.json, laplab-iterations.json,
  simtrace) returning dataclasses of arrays;
- :mod:`laplab.analysis.evaluations`: the same for a model's evaluations (simtrace, laplab's
  summary.json, DeepRacer's evaluation metrics);
- :mod:`laplab.analysis.plots`: one PNG per function (matplotlib Agg, no pyplot state);
- :mod:`laplab.analysis.report`: ``build_report(folder)``, the HTML page of ``laplab report``.
"""
