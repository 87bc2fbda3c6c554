"""Evaluation of F estimators on image pairs with ground truth (``sepfm_ros eval``).

Modules, each holding one thing:

- :mod:`~sepfm_ros.evaluation.metrics`: every metric of the report, defined once (the paper's
  Sec. 6 rules: positives, % inliers, F-score, errors, failures, hypotheses, paired comparison).
- :mod:`~sepfm_ros.evaluation.manifest`: loading pairs from a ``pairs.json``-style manifest with
  clear per-pair errors; :mod:`~sepfm_ros.evaluation.bags`: pairs from bags with ground truth.
- :mod:`~sepfm_ros.evaluation.matches_cache`: putative matches computed once per pair and cached.
- :mod:`~sepfm_ros.evaluation.methods`: the registry of compared estimators.
- :mod:`~sepfm_ros.evaluation.run`: runs methods x seeds over pairs and keeps per-run results.
- :mod:`~sepfm_ros.evaluation.report`: markdown report, CSV/JSON results and PNG figures.
- :mod:`~sepfm_ros.evaluation.cli`: the ``eval`` command.
"""
