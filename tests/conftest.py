"""Session set-up of the test suite: the aerodynamic model's numba kernels are compiled into
their on-disk cache once, before pytest-xdist starts its workers.

On a fresh checkout every process that steps a filter before the cache is written compiles the
kernels itself (about 40 s of a core each here): both workers, a campaign's jobs and the
chain's subprocesses, all at once.
"""

from __future__ import annotations

import pytest

from immukf_sitl.models.params import load_aircraft_params
from immukf_sitl.service.filter_models import RealAirModel
from immukf_sitl.service.pipeline import EstimatorPipeline, PipelineConfig


def pytest_configure(config: pytest.Config) -> None:
    if hasattr(config, "workerinput"):  # an xdist worker: the controller has warmed the cache
        return
    # one filter step compiles every kernel, whichever filter model steps it
    config_ = PipelineConfig(filter_model=RealAirModel())
    EstimatorPipeline(load_aircraft_params(), config_).warm_up()
