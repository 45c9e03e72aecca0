"""Reproductions of the source papers' claims, one experiment per claim (DESIGN §1).

Each experiment module has ``run(ctx) -> Section`` and is runnable as
``python -m experiments.<name> [--quick] [--out DIR]``; :mod:`experiments.run` runs any or all
of them and :mod:`experiments.make_report` concatenates their section files into
``REPORT.md``. See ``experiments/README.md``.
"""
