"""Benchmarks of rs_localizer: speed and accuracy measured on simulated data, rendered videos,
the node over DDS and the paper's AR experiment. Outside the installed package (the wheel does
not ship them); run from a checkout's root, e.g.

    python -m benchmarks.bench {solvers,estimate,ml}
    python -m benchmarks.bench_node
    python -m benchmarks.ar_experiment

Each module's docstring says what it measures and how; docs/accuracy.md lists them. They import
the library (their data generators are in :mod:`rs_localizer.sim`, the reference estimators in
:mod:`rs_localizer.experiments.references`); the library never imports them. The paper's
synthetic experiments are in the package (:mod:`rs_localizer.experiments`, ``rs-localizer
experiments``), as is the demo (``rs-localizer demo``).
"""
