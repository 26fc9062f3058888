"""The Python API: :func:`estimate` runs the whole chain on sensor samples held in Python.

It is ``soilocp estimate`` without files: the same validation, the same chain, the same records
(:class:`soilocp.schemas.pipeline.OcpEstimate` as dicts), from a list of dicts, a pandas or polars DataFrame, or
a sensor-log path, into a list of dicts or a pandas DataFrame.  A DataFrame holds a missing value as
NaN (or None); a missing ground speed (or position) is the sensor log's null, so NaN there is taken as
missing, not as a bad number.  pandas is optional: it is imported only for a DataFrame in or out.
"""

from __future__ import annotations

import json
import math
import os
import warnings
from pathlib import Path
from typing import Any, Iterable, Iterator, Mapping, Optional, Union

__all__ = ["estimate", "SamplesRejectedWarning", "VehicleMismatchWarning"]

#: sensor-log fields that may be missing (null): NaN there means missing (soilocp.schemas.sensor.SensorSample)
OPTIONAL_FIELDS = ("ground_speed", "position", "geo")


class SamplesRejectedWarning(UserWarning):
    """Some samples were rejected (each with its code and reason); the others were estimated."""


class VehicleMismatchWarning(UserWarning):
    """The samples do not look like the vehicle they were estimated with (soilocp.estimation.vehicle_check)."""


def _plain(value: Any) -> Any:
    """A numpy / pandas value as plain JSON data (arrays as lists, numpy scalars as numbers)."""
    if hasattr(value, "tolist"):  # numpy arrays and scalars
        return value.tolist()
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if isinstance(value, Mapping):
        return {str(k): _plain(v) for k, v in value.items()}
    return value


def _is_missing(value: Any) -> bool:
    if value is None:
        return True
    if isinstance(value, float) and math.isnan(value):
        return True
    try:  # pandas.NA, pandas.NaT
        import pandas  # noqa: F401  (only when a row came from pandas)

        return value is pandas.NA or value is pandas.NaT
    except ImportError:
        return False


def _row(row: Mapping) -> dict:
    """A sample row as the sensor log's JSON object: missing optional fields as null, ``seq`` as an
    integer (a DataFrame column with gaps holds it as a float)."""
    out = {}
    for key, value in row.items():
        key = str(key)
        if key in OPTIONAL_FIELDS and not isinstance(value, (list, tuple, Mapping)) and _is_missing(value):
            if key == "ground_speed":
                out[key] = None
            continue  # position / geo: absent
        value = _plain(value)
        if key == "seq" and isinstance(value, float) and value.is_integer():
            value = int(value)
        out[key] = value
    return out


def _lines(records: Any) -> tuple[Iterable[str], bool]:
    """``records`` as sensor-log lines, and whether they came as a pandas DataFrame."""
    if isinstance(records, (str, os.PathLike)):
        path = Path(records)
        if not path.is_file():
            raise FileNotFoundError(f"sensor log {str(path)!r}: no such file")
        return path.read_text(encoding="utf-8", errors="replace").splitlines(), False
    module = type(records).__module__.split(".")[0]
    if module == "pandas" and hasattr(records, "to_dict"):
        rows: Iterable[Mapping] = records.to_dict(orient="records")
        frame = True
    elif module == "polars" and hasattr(records, "to_dicts"):
        rows, frame = records.to_dicts(), False
    elif isinstance(records, Mapping):
        raise TypeError("records: one dict is one sample; give a list of them (or a DataFrame, or a path)")
    else:
        try:
            rows, frame = iter(records), False
        except TypeError:
            raise TypeError(f"records: a list of dicts, a pandas or polars DataFrame or a sensor-log path, not "
                            f"{type(records).__name__}") from None

    def gen() -> Iterator[str]:
        for i, r in enumerate(rows):
            if hasattr(r, "model_dump"):  # a SensorSample
                r = r.model_dump()
            if not isinstance(r, Mapping):
                raise TypeError(f"records[{i}]: a sample is a dict of the sensor-log fields, not {type(r).__name__}")
            yield json.dumps(_row(r), allow_nan=True)

    return gen(), frame


def _config(vehicle, config, torque_constant):
    from soilocp.estimation.config import PipelineConfig, calibrated_constants, load_pipeline_config
    from soilocp.model.settings_errors import describe_validation_error
    from soilocp.model.vehicle import VehicleParams, load_vehicle, user_vehicle_data
    from pydantic import ValidationError

    if isinstance(config, PipelineConfig):
        cfg = config
    elif isinstance(config, Mapping):
        data = dict(config)
        if "vehicle" in data:  # a user's robot: its curve is unchecked unless it names one
            data["vehicle"] = user_vehicle_data(data["vehicle"])
        try:
            cfg = PipelineConfig.model_validate(data)
        except ValidationError as exc:
            raise ValueError(describe_validation_error(exc, "config", PipelineConfig)) from None
    else:
        cfg = load_pipeline_config(config)
    update: dict[str, Any] = {}
    if isinstance(vehicle, VehicleParams):
        update["vehicle"] = vehicle
    elif isinstance(vehicle, Mapping):  # a user's robot: its curve is unchecked unless it names one
        try:
            update["vehicle"] = VehicleParams.model_validate(user_vehicle_data(dict(vehicle)))
        except ValidationError as exc:
            raise ValueError(describe_validation_error(exc, "vehicle", VehicleParams)) from None
    elif vehicle is not None:
        update["vehicle"] = load_vehicle(vehicle)
    if "vehicle" in update:
        update.update(calibrated_constants(update["vehicle"]))
    if torque_constant is not None:
        from soilocp.estimation.config import torque_constant_from

        update["torque_constant"] = torque_constant_from(torque_constant)
    return cfg.model_copy(update=update) if update else cfg


def estimate(
    records: Union[str, os.PathLike, Iterable[Mapping], Any],
    vehicle: Union[str, os.PathLike, Mapping, Any, None] = None,
    *,
    config: Union[str, os.PathLike, Mapping, Any, None] = None,
    torque_constant: Union[float, str, None] = None,
    full: bool = False,
    as_frame: Optional[bool] = None,
):
    """Estimate K, its soil class and the OCPs for every valid sensor sample.

    Parameters
    ----------
    records
        The samples, each with the sensor log's fields (docs/sensor-log.md): a list (or iterable) of dicts,
        a pandas or polars DataFrame with one row per sample (list-valued columns ``specific_force``,
        ``wheel_speed``, ``wheel_torque``), or the path of a sensor log (JSON Lines).  A missing
        ``ground_speed`` (None or NaN) is the log's null: no independent ground speed at that sample.
    vehicle
        The vehicle: a vehicle JSON path, a dict of its keys (README, "Describe the vehicle") or a
        :class:`soilocp.model.vehicle.VehicleParams`; default the built-in 60 kg rover.
    config
        Pipeline settings: a config JSON path, a dict or a :class:`soilocp.estimation.config.PipelineConfig`.
    torque_constant
        N m per unit of the samples' ``wheel_torque`` (a number, or the JSON file of
        ``soilocp calibrate-torque --json``); default the config's (1: torques in N m).
    full
        Also the intermediate values per record (normal forces, gross traction, ...), as ``--full``.
    as_frame
        Return a pandas DataFrame (True) or a list of dicts (False); default: a DataFrame when
        ``records`` is a pandas DataFrame, a list otherwise.

    Returns
    -------
    list of dict or pandas.DataFrame
        One record per valid sample, in order: the OCP record's fields (``status``, ``reason_code``,
        ``confirmed``, ``soil_strength``, ``soil_class``, ``mu_T``, ``S_T``, ``S_E``, ...; a missing value
        is None, NaN in a DataFrame's numeric column).  Use a value only where ``confirmed`` is true.

    Raises
    ------
    ValueError
        No sample at all, or every sample rejected (the message gives the rejection codes and the
        first reason); a bad vehicle or config (the key, the value, the closest valid key).
    TypeError
        ``records`` of a kind this function does not read.

    Warns
    -----
    SamplesRejectedWarning
        Some samples were rejected: how many, per code, and the first reason.
    VehicleMismatchWarning
        The samples do not look like the vehicle (wheel radius, torque unit).
    """
    from soilocp.estimation.estimate import EstimateSummary, estimate_samples
    from soilocp.estimation.vehicle_check import vehicle_warning

    cfg = _config(vehicle, config, torque_constant)
    lines, frame = _lines(records)
    summary = EstimateSummary()
    out = [rec for _, rec in estimate_samples(lines, cfg, full=full, summary=summary)]
    if summary.rejected:
        codes = ", ".join(f"{c} {n}" for c, n in sorted(summary.rejected_by_code().items(), key=lambda kv: -kv[1]))
        index, code, message = summary.rejected[0]
        text = (f"{len(summary.rejected)} of {summary.lines} samples rejected ({codes}); the first, sample "
                f"{index - 1} (0-based): {code}: {message}")
        if not out:
            raise ValueError(f"every sample was rejected: {text}")
        warnings.warn(text, SamplesRejectedWarning, stacklevel=2)
    elif not out:
        raise ValueError("no sample given: nothing to estimate")
    from soilocp.model.vehicle import DEFAULT_VEHICLE

    given = vehicle is not None or cfg.vehicle != DEFAULT_VEHICLE
    warning = vehicle_warning(summary.fit, cfg.vehicle, given)
    if warning:
        warnings.warn(warning.replace("--vehicle FILE", "vehicle=..."), VehicleMismatchWarning, stacklevel=2)
    if as_frame is None:
        as_frame = frame
    if not as_frame:
        return out
    try:
        import pandas
    except ImportError:
        raise ImportError("as_frame=True needs pandas: pip install pandas (or as_frame=False for a list of "
                          "dicts)") from None
    return pandas.DataFrame.from_records(out)
