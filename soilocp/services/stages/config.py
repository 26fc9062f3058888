"""Loading the physics configuration shared by the stage services."""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from soilocp.estimation.config import PipelineConfig


def pipeline_config(cfg) -> PipelineConfig:
    """The PipelineConfig named by the service config (``pipeline_config``), or the defaults.

    ValueError (a fatal config error for the service) names the file and the field.  Imported
    here, not at the top: the gateway shares this module and loads no estimation package at all.
    """
    from soilocp.estimation.config import load_pipeline_config

    return load_pipeline_config(cfg.pipeline_config)
