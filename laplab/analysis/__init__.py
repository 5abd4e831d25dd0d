"""Plots and reports from a model folder's stored logs.

- :mod:`laplab.analysis.loaders`: pure readers (TrainingMetrics.json, laplab-iterations.json,
  simtrace, evaluations with laplab's summary.json) returning dataclasses of arrays;
- :mod:`laplab.analysis.plots`: one PNG per function (matplotlib Agg, no pyplot state);
- :mod:`laplab.analysis.report`: ``build_report(folder)``, the HTML page of ``laplab report``.
"""
