"""The fleet soil map: where each soil estimate was made (:mod:`.place`), the cells it falls in
(:mod:`.cells`), how a cell fuses the estimates of many vehicles (:mod:`.fusion`) and the
databases that keep the cells (:mod:`.store`: SQLite embedded, PostgreSQL/PostGIS).  No Zenoh
here: the map service (``services/map``) is a thin adapter around it.  docs/map.md."""
