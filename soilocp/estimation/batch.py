"""Many vehicles at once: :class:`BatchPipeline`, the estimator of N vehicles whose whole step is one core
call (:class:`soilocp.estimation.estimator.Estimator`, under the name the batched service and the offline
path have used for it)."""

from __future__ import annotations

from soilocp.estimation.estimator import Estimator

#: The estimator of N vehicles (``BatchPipeline(config, n_vehicles, priors=None)``).
BatchPipeline = Estimator

__all__ = ["BatchPipeline"]
