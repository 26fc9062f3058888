"""Read-only views of the compiled core object an estimator class wraps.

The estimator banks (:class:`soilocp.estimation.observer_bank.ObserverBank`,
:class:`soilocp.estimation.soil_strength.SoilBank`) keep their per-vehicle state in a
``soilocp._core`` object and show parts of it unchanged; each such view is one
:func:`core_attribute`, so that the forwarding is written once.
"""

from __future__ import annotations

from operator import attrgetter


def core_attribute(name: str, doc: str, holder: str = "_core") -> property:
    """A read-only property that returns the wrapped core object's attribute ``name``.

    Parameters
    ----------
    name : str
        The core object's attribute (the core makes the copy an array attribute returns).
    doc : str
        The property's docstring: what the attribute holds and its shape.
    holder : str
        The wrapping instance's attribute that holds the core object.

    Returns
    -------
    property
        ``self.<holder>.<name>``, read on every access.
    """
    return property(attrgetter(f"{holder}.{name}"), doc=doc)
