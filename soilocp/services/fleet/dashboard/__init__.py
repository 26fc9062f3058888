"""The fleet dashboard (``soilocp dashboard``): Starlette app + static page, fed over Zenoh."""
