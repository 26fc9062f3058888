"""Click command modules of the ``soilocp`` console command, one module per area."""
