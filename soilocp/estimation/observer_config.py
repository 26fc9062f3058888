"""Settings of the traction observer (its noise, prior, structure and bounds): pydantic only, no
numpy, so that a process that only reads the pipeline's configuration (the OCP publisher) does not
load the physics (:mod:`soilocp.estimation.observer` has the state layout and observability).

The settings are declared once, in the compiled core (soilocp/_core/src/observer/settings.rs);
:class:`ObserverConfig` is built from those declarations, and the core's observer
(``soilocp._core.ObserverCore``) takes them whole.
"""

from __future__ import annotations

from soilocp.estimation.settings_model import model_from_core

ObserverConfig = model_from_core(
    "ObserverConfig", "observer", __name__, "Noise, prior, structure and bounds of the traction observer.")

#: the observer's structures (a ``Literal`` of the core's choices for ``structure``)
Structure = ObserverConfig.model_fields["structure"].annotation
