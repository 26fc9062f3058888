"""soilocp: soil strength K and optimal control parameters (mu_T, S_T, S_E) for wheeled robots.

This package is the pure library (no transport, no Zenoh import): the traction model, the OCP
formulas, the normal-force solver, slip, the soil-strength estimators, calibration, the vehicle
simulator, the Kalman observer and the offline pipeline.  The Zenoh services in ``services/`` are
thin adapters around it, and ``soilocp estimate`` runs the very same functions offline.

Equation numbers refer to Kim & Lee, "Soil Strength-based Estimation of Optimal Control
Parameters for Wheeled Robots on Rough Terrain"; corrections to the printed equations follow
``docs/method.md`` and are named in each docstring.

The Python API is :func:`soilocp.estimate` (docs/python-api.md): sensor samples (dicts, a DataFrame or
a sensor-log path) in, one record per sample out.
"""

__version__ = "0.1.0"

__all__ = ["__version__", "estimate"]


def __getattr__(name: str):
    """``soilocp.estimate`` (:func:`soilocp.api.estimate`), imported on first use: ``import soilocp`` stays
    lean (the OCP publisher and the gateway import the package without numpy)."""
    if name == "estimate":
        from soilocp.api import estimate

        return estimate
    raise AttributeError(f"module 'soilocp' has no attribute {name!r}")
