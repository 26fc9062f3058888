"""soilocp Zenoh services: thin adapters around the pure physics library (``soilocp``).

One OS process per service (``soilocp service NAME``): gateway, normal-force, observer,
soil-strength, ocp, and the synthetic vehicle; ``soilocp router`` runs the Zenoh router and
``soilocp run`` starts them all.  Keys are in :mod:`soilocp.schemas.keys`, messages in :mod:`schemas`.
Only this package imports Zenoh.
"""
