"""Loading the physics configuration shared by the stage services."""

from __future__ import annotations

from soilocp.estimation.pipeline import PipelineConfig, load_pipeline_config


def pipeline_config(cfg) -> PipelineConfig:
    """The PipelineConfig named by the service config (``pipeline_config``), or the defaults.

    ValueError (a fatal config error for the service) names the file and the field.
    """
    return load_pipeline_config(cfg.pipeline_config)
