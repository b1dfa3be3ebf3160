"""Generic Sobol' global sensitivity analysis: design, runner, estimators, bootstrap.

A study is a Problem, a model callable and the names of its outputs::

    from gsa import Problem, Study, saltelli_design, run, analyze

    problem = Problem(names=("x1", "x2"), bounds=((0, 1), (1e-3, 1e-1)),
                      dists=("uniform", "loguniform"))
    study = Study("demo", problem, model, output_names=("y",))
    design = saltelli_design(problem, N=2**12, seed=1)
    result = run(study, design, "out/demo", executor="processes").analyze()
    result.write_csv("out/demo/indices.csv")

This package does not import the application (``sam``); errors are
:class:`GSAError` (a ValueError) for the CLI layer to convert. See docs/gsa.md.
"""

from gsa.analyze import CSV_COLUMNS, SobolResult, analyze
from gsa.bootstrap import BootstrapResult, bootstrap_sobol, resample_counts
from gsa.design import Design, Samples, saltelli_design
from gsa.errors import (
    GSAError,
    GSAWarning,
    NonFiniteWarning,
    SamplingWarning,
    ZeroVarianceWarning,
)
from gsa.estimators import (
    DEFAULT_ESTIMATOR,
    ESTIMATORS,
    interaction,
    ranking,
    sobol_indices,
)
from gsa.nonfinite import NonFiniteReport
from gsa.problem import DISTRIBUTIONS, SALIB_NAMES, Problem
from gsa.runner import EXECUTORS, RunResult, Study, run

__all__ = [
    "CSV_COLUMNS",
    "DEFAULT_ESTIMATOR",
    "DISTRIBUTIONS",
    "ESTIMATORS",
    "SALIB_NAMES",
    "EXECUTORS",
    "BootstrapResult",
    "Design",
    "GSAError",
    "GSAWarning",
    "NonFiniteReport",
    "NonFiniteWarning",
    "Problem",
    "RunResult",
    "Samples",
    "SamplingWarning",
    "SobolResult",
    "Study",
    "ZeroVarianceWarning",
    "analyze",
    "bootstrap_sobol",
    "interaction",
    "ranking",
    "resample_counts",
    "run",
    "saltelli_design",
    "sobol_indices",
]
