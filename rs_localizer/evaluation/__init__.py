"""Evaluation: the paper's experiments, the AR experiment, benchmarks and the demo.

The top layer with :mod:`rs_localizer.cli`: it composes simulation, estimation and ROS;
nothing else imports it.

    python -m rs_localizer.evaluation.bench {solvers,estimate,ml}
    python -m rs_localizer.evaluation.bench_node
    python -m rs_localizer.evaluation.experiments   (= rs-localizer experiments)
    python -m rs_localizer.evaluation.ar_experiment
"""
